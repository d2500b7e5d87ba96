"""ament_python build entry: everything is declared in setup.cfg."""

from setuptools import setup

setup()
