"""Training the network: query augmentation, batches, the weighted infoNCE loss, the resumable
training loop, model selection on held-out views of seen objects, data-parallel helpers.

May import: :mod:`helpers.net`, :mod:`helpers.data`, :mod:`helpers.core`; never
:mod:`helpers.search` or :mod:`helpers.evaluation` (siblings).
"""
