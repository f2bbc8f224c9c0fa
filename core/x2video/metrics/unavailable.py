"""LPIPS and FVD: the paper reports them, but their network weights cannot be had offline here.

docs/ARCHITECTURE.md "Measuring it": a metric whose weights cannot be had offline is reported as missing, never replaced
by a look-alike under its name. These are the reasons, checked against the PyPI packages.
"""
from __future__ import annotations

#: metric name -> why it is not computed
UNAVAILABLE: dict[str, str] = {
    "lpips": (
        "LPIPS (Zhang et al. 2018) needs an ImageNet-pretrained AlexNet/VGG backbone: the PyPI package "
        "'lpips' ships only its small linear heads and downloads the backbone through torchvision at "
        "run time; torchvision cannot be installed beside our CPU torch and no package ships the backbone weights"
    ),
    "fvd": (
        "FVD (Unterthiner et al. 2018) needs the Kinetics-400 I3D network: no PyPI package ships its weights "
        "('cd-fvd' downloads them at run time) and model hubs are not reachable"
    ),
}


def unavailable_metrics() -> dict[str, dict[str, object]]:
    """{"lpips": {"value": None, "available": False, "reason": ...}, "fvd": {...}} for results files."""
    return {name: {"value": None, "available": False, "reason": reason} for name, reason in UNAVAILABLE.items()}
