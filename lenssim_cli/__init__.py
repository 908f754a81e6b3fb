"""lenssim_cli: the ``lenssim`` command, on top of both libraries.

Layers (checked by import-linter in CI): :mod:`lenssim` (optics) <- :mod:`pipeline` (images) <-
:mod:`lenssim_cli` (argparse, printing, exit codes). The library packages hold no argparse and
never import this one. Each command module registers its subcommands (``register(subparsers)``);
:mod:`lenssim_cli.main` assembles the parser from :data:`lenssim_cli.main.COMMAND_MODULES`.
"""
