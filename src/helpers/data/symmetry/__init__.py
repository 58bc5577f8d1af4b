"""Visual symmetries of an object, found by a rule from its mesh and its renders.

Two stages (:mod:`.surface`, :mod:`.appearance`), combined in :mod:`.rule`; the command
(``python -m helpers.data.symmetry``, :mod:`.__main__`) applies the rule to the manifest's objects and
writes the declarations, with their evidence, into ``data_manifest.yaml``.
"""
