"""``python -m analysis.calibration``: runs the study alone (as ``wmr analyze calibration``
does)."""

import sys

if __name__ == "__main__":  # a guard: Dask's worker processes re-import the main module
    from analysis import calibration as study
    sys.exit(study.main())
