"""Helpers for a reproducible study of retrieval-based 3D orientation estimation.

Data flows one way through the modules::

    manifest -> meshes -> render -> datasets -> model -> train
             -> features -> retrieval -> metrics -> report

Conventions (stated once, used everywhere):

* Camera: OpenCV (x right, y down, z forward).
* Rotations: 3x3 matrices ``R_m2c`` mapping model to camera coordinates.
* Angles in reports: degrees.

Importing this package has no side effects: nothing is rendered, downloaded,
or configured until a function is called.
"""

__version__ = "0.1.0"
