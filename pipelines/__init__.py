"""End-to-end orchestration across every package: the stage cache (:mod:`.stages`), ``uss-demo``
(:mod:`.demo`, its data set :mod:`.demo_data`, table and plots :mod:`.demo_report`) and
``uss-eval`` (:mod:`.evaluate`)."""
