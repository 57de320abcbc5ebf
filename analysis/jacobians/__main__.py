"""``python -m analysis.jacobians``: runs the study alone (as ``wmr analyze jacobians`` does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import common
    from analysis import jacobians as study
    sys.exit(common.main(study))
