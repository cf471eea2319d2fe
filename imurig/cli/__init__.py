"""The command line: ``imurig COMMAND``."""
from imurig.cli.main import main

__all__ = ["main"]
