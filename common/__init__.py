"""What every part of the project shares, and nothing else: one error type for bad input, atomic
writes, safe reading of YAML and JSON, declarative config schemas and the command-line error
boundary. Imports nothing of ours, so `geometry`, `dataset_tools`, `model` and the Blender scripts
can all use it."""

from .cli import EXIT_BAD_INPUT, EXIT_ENVIRONMENT, EXIT_INTERRUPTED, EXIT_PROBLEMS, run_cli
from .errors import ConfigError, InputError, MachineError
from .files import (atomic_path, clean_stale_temps, read_json, read_text, read_yaml, write_bytes_atomic, write_json_atomic,
                    write_text_atomic)

__all__ = [
    "InputError", "ConfigError", "MachineError", "run_cli", "EXIT_BAD_INPUT", "EXIT_ENVIRONMENT", "EXIT_INTERRUPTED", "EXIT_PROBLEMS",
    "atomic_path", "write_bytes_atomic", "write_text_atomic", "write_json_atomic", "read_text", "read_json", "read_yaml",
    "clean_stale_temps",
]
