"""``python -m analysis.margins``: runs the study alone (as ``wmr analyze margins`` does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import common
    from analysis import margins as study
    sys.exit(common.main(study))
