"""The method-choice layer: what methods exist, their knobs and build options (``registry``),
and the measured data ``method="auto"`` chooses from (``choice``). Pure data: imports only the
foundation (errors, caches), never a device or an operation."""
from .registry import (BLUR_METHODS, BORDERS, METHODS, TEXTURED_BLUR_METHODS, BlurChoice,
                       InversionChoice, MethodConfig)

__all__ = ["BLUR_METHODS", "BORDERS", "METHODS", "TEXTURED_BLUR_METHODS", "BlurChoice",
           "InversionChoice", "MethodConfig"]
