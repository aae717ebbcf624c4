"""Builds the compiled loops of the vision stages (``companion/vision/_*.pyx``).

Everything else about the package is declared in pyproject.toml.
"""

from Cython.Build import cythonize
from setuptools import Extension, setup

DIRECTIVES = {"language_level": 3, "boundscheck": False, "wraparound": False,
              "cdivision": True, "initializedcheck": False}

setup(
    ext_modules=cythonize(
        [Extension(f"companion.vision._{name}", [f"companion/vision/_{name}.pyx"])
         for name in ("lines", "vanishing", "corners", "obstacles")],
        compiler_directives=DIRECTIVES,
    ),
)
