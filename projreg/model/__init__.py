"""The SSJM registration network: backbone -> SSJM -> transformer -> matching -> propagation -> upsampling."""

from .net import MODEL_CONFIGS, SSJMFlow, build_model, count_parameters
from .ssjm import SSJM

__all__ = ["MODEL_CONFIGS", "SSJM", "SSJMFlow", "build_model", "count_parameters"]
