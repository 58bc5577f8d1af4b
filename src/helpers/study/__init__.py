"""What the notebooks call: parameters and their checks, the pipeline steps (prepare data,
train or load, reference bank, evaluate), the paper's protocol, ablation variants, the model zoo,
figures, reports, the batch runner, the explorer and bring-your-own.

May import: every other layer (it is the top one).
"""
