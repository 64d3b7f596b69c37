"""Package discovery for the parts of mi_nest that live outside ``mi_nest/``.

``pyproject.toml`` holds the metadata. The top-level ``plugins/`` and ``scenes/``
folders install as ``mi_nest.plugins`` and ``mi_nest.scenes``; every subpackage
(and every scene subfolder of data) is found here, so a new one cannot be left out of
the wheel.
"""
from setuptools import find_namespace_packages, find_packages, setup

MAPPED = {"mi_nest.plugins": "plugins", "mi_nest.scenes": "scenes"}


def discover():
    packages = find_packages(include=["mi_nest", "mi_nest.*"])
    for package, folder in MAPPED.items():
        packages.append(package)
        packages += [f"{package}.{sub}" for sub in find_namespace_packages(where=folder, exclude=["*__pycache__*"])]
    return packages


setup(packages=discover(), package_dir=MAPPED)
