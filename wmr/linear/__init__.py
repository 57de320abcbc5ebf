"""Linearised-loop tools: the sampled-data loops of PID and backstepping (``loops``), their
stability regions (``loop_regions``), margins, Floquet analysis on periodic references and the
python-control comparator (``nlsys``)."""
