"""One exception type for bad input, so the CLI can print one line and exit 2 without a traceback."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a file, a field or a flag. The message names it and says what is wrong."""

    def __init__(self, source: str, problem: str) -> None:
        self.source = source
        self.problem = problem
        super().__init__(f"{source}: {problem}")

    def __reduce__(self) -> tuple[type[InputError], tuple[str, str]]:
        # picklable with its two fields: a worker process (the bench's) can hand it back
        return (type(self), (self.source, self.problem))
