"""CLI subcommands. Each module exposes `register(subparsers)`; `app.cli` wires them up."""
