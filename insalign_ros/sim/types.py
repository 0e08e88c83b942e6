"""The recording type lives in core/recording.py (simulator, readers and session share it); re-exported here."""

from ..core.recording import ImuSpec, ScenarioData  # noqa: F401
