"""``python -m analysis.regimes``: runs the study alone (as ``wmr analyze regimes`` does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import regimes as study
    sys.exit(study.main())
