"""The operations layer: albedo inversion (``invert``), the device evaluation of the physics
functions (``physics_eval``), bands of rows (``bands``) and the blur subpackage (``blur``).
Operations take their device explicitly (``device=`` resolved once to a Runtime and passed
down) and import only the layers below: methods, device, physics, foundation."""
