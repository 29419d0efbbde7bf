"""One module per ``ogiflow`` subcommand (or subcommand group member).

Each module exposes ``register(root)`` where ``root`` is the top-level subparsers
object; modules import their heavy dependencies inside the command function so that
``ogiflow --help`` stays fast.
"""
