"""The exceptions that mean "bad input" (reported in one line by the CLI)."""

from rig.metrics import MetricsError
from rig.recording import RecordingError
from rig.survey import SurveyError
from rig.usdlog import LogFormatError

USER_ERRORS: tuple[type[Exception], ...] = (LogFormatError, SurveyError, RecordingError, MetricsError,
                                            ValueError, OSError)
