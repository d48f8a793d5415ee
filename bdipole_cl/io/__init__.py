"""The I/O layer: images (``images``), texture batches (``batch``) and the file-to-file blur
(``blur_file``). Imports the operations and everything below them, never an application."""
