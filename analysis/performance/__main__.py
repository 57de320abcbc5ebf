"""``python -m analysis.performance``: runs the study alone (as ``wmr analyze performance``
does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import common
    from analysis import performance as study
    sys.exit(common.main(study))
