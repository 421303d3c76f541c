"""The Hydra config tree (YAML package data); Hydra apps load it as ``pkg://uss_slam.configs``."""
