"""The applications layer: the command line (``cli``), the error-vs-runtime report
(``report``), the cross-check tables (``crosscheck``), the built-in example (``demo``) and the
benchmark helpers (``benchmark``). May import any layer."""
