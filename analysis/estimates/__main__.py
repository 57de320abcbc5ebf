"""``python -m analysis.estimates``: runs the study alone (as ``wmr analyze estimates`` does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import common
    from analysis import estimates as study
    sys.exit(common.main(study))
