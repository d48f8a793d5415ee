"""The physics layer: the float64 model (``reference``, the one host-side truth, twinned with
kernels/bdipole.h), the Fresnel moments it is built on (``fresnel``), the models' registry
(``models``) and the inversion tables built from it (``tables``). Imports nothing of the
package but the foundation (caches, vocabulary)."""
