"""``python -m analysis.boundedness``: runs the study alone (as ``wmr analyze boundedness``
does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import boundedness as study
    from analysis import common
    sys.exit(common.main(study))
