"""Foundations every layer may use: paths and the cache root, atomic file I/O, inter-process locks,
device and precision choice, rotation maths, the network's input transform (local normalisation), the
in-memory view container, and the typed configurations of the study (:mod:`helpers.core.configs`).

May import: nothing else of ``helpers`` (third-party libraries only).
"""
