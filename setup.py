"""Packaging detail pyproject.toml cannot say: the repository keeps the C templates at the top
level (templates/, see DESIGN.md), and the installed package carries them as the package
generator.templates (generator/paths.py finds them through importlib.resources)."""
from setuptools import find_namespace_packages, setup

setup(
    packages=find_namespace_packages(include=["generator*", "firmware_sim*"], exclude=["*.__pycache__"])
    + ["generator.templates"],
    package_dir={"generator.templates": "templates"},
)
