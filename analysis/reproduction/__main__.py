"""``python -m analysis.reproduction``: runs the study alone (as ``wmr analyze reproduction``
does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import common
    from analysis import reproduction as study
    sys.exit(common.main(study))
