"""The package list of the wheel, computed: each top-level folder of ``FOLDERS`` installs as a
sub-package of the ``uss_slam`` namespace (``models/`` -> ``uss_slam.models``), and so does every
folder below it, so that a new sub-package or config folder needs no edit. setuptools'
``packages.find`` cannot add the ``uss_slam.`` prefix; everything else is in pyproject.toml."""

from setuptools import find_namespace_packages, setup

# ``configs/`` is the Hydra config tree, shipped as package data (pyproject's package-data).
FOLDERS = (
    "core",
    "models",
    "datasets",
    "synthetic",
    "train",
    "export",
    "slam_eval",
    "pipelines",
    "testing",
    "configs",
)

setup(
    package_dir={f"uss_slam.{folder}": folder for folder in FOLDERS},
    packages=[
        f"uss_slam.{folder}" + (f".{sub}" if sub else "")
        for folder in FOLDERS
        for sub in ["", *find_namespace_packages(folder, exclude=["__pycache__", "*.__pycache__"])]
    ],
)
