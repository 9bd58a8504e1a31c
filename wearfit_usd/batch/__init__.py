"""`wearfit batch`: many references x targets x clips on Dask.

:mod:`.jobs` reads and expands a job file, :mod:`.cache` keys every result by
the bytes of its inputs, its options and the code version, :mod:`.graph`
builds and runs the Dask task graph (shared fits, reads and plans), and
:mod:`.report` writes ``report.json``, ``report.md`` and the contact sheets.
"""
