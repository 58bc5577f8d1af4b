"""The benchmark's data: the manifest of meshes and photos, rendering (references, real-like and
tabletop queries, depth), cached view sets, the symmetry rule that declares each object's visual
symmetries (:mod:`helpers.data.symmetry`), the T-LESS-like parts and set, and BOP-format reading
and writing.

May import: :mod:`helpers.core`.
"""
