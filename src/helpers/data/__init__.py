"""The benchmark's data: the manifest of meshes and photos, rendering (references, real-like and
tabletop queries, depth), cached view sets, the T-LESS-like parts and set, and BOP-format reading
and writing.

May import: :mod:`helpers.core`.
"""
