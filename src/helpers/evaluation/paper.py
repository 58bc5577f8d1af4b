"""The paper's published numbers, to set beside ours in reports (never used as results).

Source: Zhao, Hu, Salzmann, "Fusing Local Similarities for Retrieval-based 3D
Orientation Estimation of Unseen Objects", ECCV 2022, as summarised in
``docs/method.md``. All are percentages on real LineMOD / LineMOD-O /
T-LESS images, so they describe a different benchmark from our rendered one:
reports compare trends, not values.
"""

from __future__ import annotations

#: LineMOD, unseen objects, Rota. Acc. (%) per split and mean; Class. Acc. mean.
LINEMOD_UNSEEN_ROT_ACC = {1: 89.55, 2: 79.04, 3: 75.96, "mean": 81.52}
LINEMOD_UNSEEN_CLASS_ACC_MEAN = 93.10
LINEMOD_SEEN_ROT_ACC_MEAN = 95.35
LINEMOD_O_UNSEEN_ROT_ACC_MEAN = 50.34
TLESS_ACC = 78.73  # err_vsd <= 0.3 (Table 3: trained on LineMOD, tested on T-LESS's Primesense test scenes)

#: T-LESS Rota. Acc. (%) of every method of the paper's Table 3 (err_vsd <= 0.3, rotation only).
TLESS_TABLE3 = {"HOG": 74.22, "LD": 24.19, "NetVLAD": 56.46, "PFS": 17.92, "MPE": 66.88, "GDR-Net": 11.89,
                "Ours (paper)": 78.73}

#: Baselines, LineMOD unseen mean Rota. Acc. (%).
BASELINES_UNSEEN_ROT_ACC = {"HOG": 33.13, "NetVLAD": 26.61, "MPE": 47.35, "Ours (paper)": 81.52}

#: Fusion ablation, split #1 unseen Rota. Acc. (%). "avg" is read off a figure (about).
FUSION_SPLIT1 = {"avg": 80.9, "sigmoid": 88.57, "softmax": 89.03, "adaptive": 89.55}

#: Components, split #1 unseen Rota. Acc. (%): (local_norm, weighted_loss) -> acc.
COMPONENTS_SPLIT1 = {(False, False): 85.91, (True, False): 89.25, (False, True): 87.14, (True, True): 89.55}


def component_label(local_norm: bool, weighted_loss: bool) -> str:
    """Label of a components variant (paper Table 5), e.g. "LN on, wInfoNCE off" (no "=": papermill's
    parameter parser cannot read a string holding one)."""
    return f"LN {'on' if local_norm else 'off'}, wInfoNCE {'on' if weighted_loss else 'off'}"


COMPONENT_LABELS = tuple(component_label(ln, wl) for ln in (False, True) for wl in (False, True))


#: Fast retrieval vs greedy search (V100, 13 objects x 10,000 references).
FAST_VS_GREEDY = {"fast": {"rot_acc": 89.55, "seconds_per_query": 0.42},
                  "greedy": {"rot_acc": 95.93, "seconds_per_query": 30.74}}

#: Paper's claim on scales (Fig. 5a): multi-scale beats global and any single scale.
SCALES_CLAIM = "multi-scale [32,16,13] > any single scale > global descriptor"

#: Paper's claim on reference count (Fig. 7): accuracy rises with references and saturates.
REFERENCE_COUNT_CLAIM = "Rota. Acc. rises with the number of references and saturates; queries/s falls"
