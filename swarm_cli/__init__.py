"""The ``swarm`` command line: the top layer, parsing options and printing what ``inchworm`` (the library) returns.

Entry points (``swarm_cli.main.main``, ``entry.run_standalone``) limit BLAS to one thread;
importing the package changes nothing.
"""
