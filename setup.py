# cffi's build hook is a setup() keyword with no pyproject.toml equivalent, so this
# file exists only to register it; all other metadata lives in pyproject.toml.
from setuptools import setup

setup(cffi_modules=["csrc/build_core.py:ffibuilder"])
