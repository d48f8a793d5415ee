"""Jobs: what a run computes, as typed records, and the one runner that runs them.

A ``job.Job`` is one unit of work (kind, source, output, every input by role, the typed work
to do, the up-to-date key); ``runner.run_job`` runs one on a runtime and returns its
``results.FileResult``. The texture batch (``batch.process_textures``, ``bdipole-cl invert``),
the file blur (``bdipole-cl blur``), the scene bake (``scene``) and the Dask paths
(``bdipole_cl.dask``, which maps the runner over jobs on workers) all build jobs and call
that runner. Reading, writing and decoding images is ``bdipole_cl.io``'s.
"""
