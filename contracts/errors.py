"""The one error type a person can cause: a bad vehicle file, table or query.

Its message is a single line meant to be printed as is (the CLI prints it and exits non-zero).
"""


class ContractError(Exception):
    """A user-facing, one-line error about a vehicle file, a table or a query."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))
