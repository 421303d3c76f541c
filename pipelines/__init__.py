"""End-to-end orchestration across every package: the stage cache (:mod:`.stages`), ``uss-demo``
(:mod:`.demo`, table and plots :mod:`.demo_report`), ``uss-experiments`` (:mod:`.experiments`),
the synthetic data set recipe both render (:mod:`.synthetic_data`) and ``uss-eval``
(:mod:`.evaluate`)."""
