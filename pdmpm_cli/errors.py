"""Error types that map to the CLI's exit codes (2: bad input, 1: failed simulation)."""


class PdmpmError(Exception):
    """Base class: an error with a message meant for the user, printed without a traceback."""

    exit_code = 1


class InputError(PdmpmError):
    """Bad input: malformed or invalid scene, missing or broken mesh, corrupt output to read. Exit code 2."""

    exit_code = 2


class SimulationError(PdmpmError):
    """The simulation failed (NaN, runaway energy, particles leaving the domain). Exit code 1."""

    exit_code = 1


class OutputError(PdmpmError):
    """An output could not be written (a full disk, a file-size limit, no permission); what was written before
    stays complete. Exit code 1."""

    exit_code = 1
