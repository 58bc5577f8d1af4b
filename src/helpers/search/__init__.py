"""Retrieval: reference features cached on disk, the reference bank, greedy search, the
authors' fast retrieval, coarse-to-fine search and the choice of its settings.

May import: :mod:`helpers.net`, :mod:`helpers.data`, :mod:`helpers.core`; never
:mod:`helpers.training` or :mod:`helpers.evaluation` (siblings).
"""
