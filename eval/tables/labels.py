"""Row labels of the paper's tables: the one place where method and ablation names are spelled.

Ablations are matched by their paper ID (the `a<k>` prefix of the config name), so
`a9_freeze_both` and `a9_freeze_opacity_scaling` both read "A9: Freeze opacity & scaling".
"""
from __future__ import annotations

import re

REFERENCE_ABLATION = "full"

# Table 1: method config name -> the paper's row name; the order is the paper's row order.
METHOD_LABELS = {
    "r3dg": "R3DG",
    "gaussianshader": "GaussianShader",
    "lumigauss": "LumiGauss",
    "irgs": "IRGS",
    "gs_ir": "GS-IR",
    "materialanything": "MaterialAnything",
    "joint_ir": "Joint IR (GS-IR-style)",
    "no_decomposition": "No decomposition",
    "light_fit": "Light read-out (training-free)",
    "gspi": "GS-PI (ours)",  # one name for the method in every table, terminal and docs alike
}

# Tables 2 and 3: paper ID -> the paper's row name (Table 2: A1-A5, Table 3: A6-A9).
ABLATION_LABELS = {
    "a1": "A1: w/o global semantic prior",
    "a2": "A2: w/o view-direction conditioning signal",
    "a3": "A3: N_pts = 1024",
    "a4": "A4: N_pts = 1024, N_lat = 384",
    "a5": "A5: Direct multi-view injection",
    "a6": "A6: w/o distill",
    "a7": "A7: Freeze opacity",
    "a8": "A8: Freeze scaling",
    "a9": "A9: Freeze opacity & scaling",
}
FULL_LABEL = "GS-PI (ours, Full)"


def ablation_id(ablation: str) -> str | None:
    """Paper ID ("a1".."a9") of an ablation config name, None for the full model/others."""
    match = re.match(r"(a\d)(?:_|$)", ablation)
    return match.group(1) if match else None


def row_label(method: str, ablation: str, table: str) -> str:
    """The paper's name for a row: methods in Table 1, ablations in Tables 2 and 3.

    A row the paper does not name keeps its config name, so nothing is ever dropped.
    """
    if table == "table1" or method != "gspi":
        label = METHOD_LABELS.get(method, method)
        return label if ablation == REFERENCE_ABLATION else f"{label} [{ablation}]"
    if ablation == REFERENCE_ABLATION:
        return FULL_LABEL
    return ABLATION_LABELS.get(ablation_id(ablation) or "", ablation)


def row_order(method: str, ablation: str) -> tuple:
    """Sort key giving the paper's row order: listed methods, then others, A1..A9, Full last."""
    is_reference = method == "gspi" and ablation == REFERENCE_ABLATION
    methods = list(METHOD_LABELS)
    aid = ablation_id(ablation)
    return (is_reference, methods.index(method) if method in methods else len(methods), method,
            aid is None, aid or "", ablation)
