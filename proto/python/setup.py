"""pip install ./proto/python — offline, with Debian's python3-numpy and python3-websockets.

A setup.py and no pyproject.toml on purpose: pip then builds with the setuptools
already installed (Debian's python3-setuptools) instead of fetching one into an
isolated build environment, which fails without the network. In a virtual
environment that sees Debian's packages:

    /usr/bin/python3 -m venv --system-site-packages ~/.venv/oceand
    ~/.venv/oceand/bin/pip install ./proto/python
"""
from setuptools import setup

setup(
    name="oceand",
    version="0.1.0",
    description="Client of the oceand ocean daemon: frame decoder, cascades summed, queries and probes",
    packages=["oceand"],
    python_requires=">=3.9",
    install_requires=["numpy", "websockets>=10"],
)
