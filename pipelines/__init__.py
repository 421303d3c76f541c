"""End-to-end orchestration across every package: the ``uss-demo`` pipeline (stages, caching,
tables and plots)."""
