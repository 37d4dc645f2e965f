"""One module per ``capstan`` subcommand; each provides ``HELP``, ``add_arguments(parser)``
and ``run(args) -> exit code`` (see :mod:`capstan.tools.cli`).

May import the other ``capstan.tools`` subpackages and everything below ``tools``.
"""
