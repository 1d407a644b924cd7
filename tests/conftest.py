"""pytest setup shared by every test: node modules importable under CPython."""
from ropemon.firmware import install_shim

install_shim()
