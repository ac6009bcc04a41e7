"""The one error type for bad input.

Every check of something a user gave (a config, a recipe, a rig, a calibration, a data set file, a
checkpoint) raises an `InputError` (or a subclass that says which kind of input) whose message is
one line naming the file and the field: `path: section.field: what is wrong`. The command-line
boundary (`common.cli.run_cli`) prints it and exits with code 2.
"""


class InputError(ValueError):
    """Bad input: the message is one line naming the file and field."""


class ConfigError(InputError):
    """A config or recipe file (YAML) that does not validate."""


class MachineError(Exception):
    """The machine cannot do what a valid input asks (no CUDA device, ...): one line, exit 1."""
