"""The method-choice layer: what methods exist, their knobs and build options (``registry``),
and the measured data ``method="auto"`` chooses from (``choice``). Pure data: imports only the
foundation (errors, caches, vocabulary), never a device or an operation."""
from .registry import (BLUR_METHOD, BLUR_METHODS, BORDER, BORDERS, METHOD, METHOD_OR_AUTO,
                       METHODS, MFP_KIND, MFP_KINDS, OUTPUT, OUTPUTS, TEXTURED_BLUR_METHODS,
                       BlurChoice, BlurMethod, InversionChoice, InversionMethod, MethodConfig)

__all__ = ["BLUR_METHOD", "BLUR_METHODS", "BORDER", "BORDERS", "METHOD", "METHOD_OR_AUTO",
           "METHODS", "MFP_KIND", "MFP_KINDS", "OUTPUT", "OUTPUTS", "TEXTURED_BLUR_METHODS",
           "BlurChoice", "BlurMethod", "InversionChoice", "InversionMethod", "MethodConfig"]
