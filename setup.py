"""Packages are discovered, not listed: every folder with an ``__init__.py`` under the design
card's top-level folders lands under the one ``panogrf`` namespace (``app/viewer`` ->
``panogrf.app.viewer``), so a new subpackage cannot be left out of the wheel."""

from setuptools import find_packages, setup

ROOTS = ("app", "model", "renderer")
DATA = ("shaders", "assets")  # folders of files, importable for importlib.resources

package_dir = {f"panogrf.{name}": name for name in (*ROOTS, *DATA)}
packages = [f"panogrf.{name}" for name in DATA]
for root in ROOTS:
    packages.append(f"panogrf.{root}")
    packages += [f"panogrf.{root}.{sub}" for sub in find_packages(root)]

setup(package_dir=package_dir, packages=packages)
