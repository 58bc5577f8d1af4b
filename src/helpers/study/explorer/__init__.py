"""The explorer (``notebooks/10_explore.ipynb``): :mod:`.query` encodes a split's reference bank and puts one query
under the microscope; :mod:`.panels` holds its two ipywidgets panels (a benchmark query, bring your own)."""
