"""How each experiment scores models, as steps the notebooks call: :mod:`.linemod` (the paper's protocol on the
LineMOD-like splits, Tables 1-2), :mod:`.tless` (Table 3 on the T-LESS-like set), :mod:`.variants` (trained
variants compared on the same queries: the ablations), :mod:`.screens` (training-regime screens on seen-object
views), :mod:`.budget` (a split's two zoo budgets on the same test queries) and :mod:`.gap_inputs` (what the gap account reads from the other notebooks' files)."""
