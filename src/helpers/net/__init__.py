"""The network: encoder/decoder backbone, multi-scale local features, the adaptive fusion of
their similarity maps, and the compiled CPU kernel (fusion and farthest point sampling loops).

May import: :mod:`helpers.core`.
"""
