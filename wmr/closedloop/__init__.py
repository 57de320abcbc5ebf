"""The closed loop and its records: the step written once and its two drivers (``step``), a run's
set-up (``runsetup``), ``simulate`` (``sim``), the record (``result``), per-step probes, the RMSE
(``metrics``) and the measures of a run (``measures``)."""
