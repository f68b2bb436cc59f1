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


class SceneValueError(InputError):
    """Bad input the schema cannot see (a broken mesh file, a body larger than the domain), tied to the scene key
    whose value causes it: `key` (a path such as ('bodies', 0, 'geometry', 'shape', 'path')), or, until the caller
    knows where it sits, the scene object `subject` it concerns and the `field` of it. The runner points the
    message at the key's line in the scene file (`scene.loader.locate`)."""

    def __init__(self, message: str, key: tuple = (), subject=None, field: str = ""):
        super().__init__(message)
        self.message, self.key, self.subject, self.field = message, tuple(key), subject, field

    def __str__(self) -> str:
        return f"{'.'.join(map(str, self.key))}: {self.message}" if self.key else self.message


class OutputError(PdmpmError):
    """An output could not be written (a full disk, a file-size limit, no permission); what was written before
    stays complete. Exit code 1."""

    exit_code = 1
