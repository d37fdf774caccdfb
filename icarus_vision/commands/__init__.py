"""CLI commands, one module each; every module registers its command on ``icarus_vision.cli.app``."""
