"""Packages of the wheel (pyproject.toml holds the rest): the code packages, and the presets
(configs/) and scene recipes (scenes/) as package data of `fisheye_bev_data`, where
common.resources finds them in an installed wheel (in a checkout it reads configs/ and scenes/)."""

from setuptools import find_packages, setup

CODE = ["common*", "geometry*", "dataset_tools*", "blender_scripts*", "model*"]
DATA = {"fisheye_bev_data.configs": "configs", "fisheye_bev_data.scenes": "scenes"}

setup(
    packages=find_packages(include=CODE) + list(DATA),
    package_dir=DATA,  # their files: [tool.setuptools.package-data] in pyproject.toml
)
