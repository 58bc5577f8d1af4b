"""Scoring: rotation errors and accuracies, the VSD error, statistics (object-weighted bootstrap,
paired differences, seed spread, verdicts), the HOG baseline, the paper's numbers and the claims
of a report.

May import: :mod:`helpers.net`, :mod:`helpers.data`, :mod:`helpers.core`; never
:mod:`helpers.training` or :mod:`helpers.search` (siblings).
"""
