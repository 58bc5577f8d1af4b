"""What the notebooks call, in folders that show what each part is for:

* top-level modules: parameters and their checks (``parameters``, ``parameter_rules``), the pipeline steps
  (``pipeline``: prepare data, train or load, reference bank, evaluate), the model zoo (``zoo``), bring your own
  object (``byo``), figures, provenance, the report (``report``, ``report_format``);
* ``protocols/``: how each experiment scores models (the paper's protocol, T-LESS-like, ablation variants,
  training screens, the gap account's inputs);
* ``experiments/``: one module per notebook (its parameter checks, claims, report section, headline);
* ``explorer/``: the explorer notebook's steps and panels;
* ``cli/``: the command-line tools (runner, zoo, byo, cache, readme, ddp_train).

May import: every other layer (it is the top one).
"""
