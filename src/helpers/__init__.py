"""Helpers for a reproducible study of retrieval-based 3D orientation estimation.

The package is cut into layers (sub-packages); a layer imports only the layers below it
(``tests/test_architecture.py`` runs the import-linter contracts of ``pyproject.toml``)::

    study                                   what notebooks call (top)
    training | search | evaluation          independent of each other
    net | data                              independent of each other
    core                                    configs, rotations, files, locks (bottom)

Conventions (stated once, used everywhere):

* Camera: OpenCV (x right, y down, z forward).
* Rotations: 3x3 matrices ``R_m2c`` mapping model to camera coordinates.
* Angles in reports: degrees.

Importing this package has no side effects: nothing is rendered, downloaded,
or configured until a function is called.
"""

__version__ = "0.1.0"
