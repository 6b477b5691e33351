"""The ``fleetslam`` command line: one module per command group, each parsing its arguments, calling the Python API
and printing the result.

It exports no names: the entry point is the console script, :func:`fleetslam.cli.main.main` (a name ``main`` here
would be shadowed by the submodule of the same name as soon as that is imported).
"""

__all__: list[str] = []
