"""Exceptions of dcmotor_id: each says what is wrong and what to do."""


class DcMotorIdError(Exception):
    """Base class of every error this package raises on purpose."""


class InputDataError(DcMotorIdError):
    """The data cannot be used as given (format, values, sampling)."""


class NotIdentifiableError(DcMotorIdError):
    """The data do not excite the motor enough to identify the named parameters."""


class FitError(DcMotorIdError):
    """The fit failed or gave a result that is not physical."""
