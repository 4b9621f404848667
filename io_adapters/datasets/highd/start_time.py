"""When a highD recording began, as well as its recordingMeta says: ``month`` ("09.2017"),
``weekDay`` ("Tue") and ``startTime`` ("08:38"), local time in Germany. highD publishes no day, so
the start is placed on the first such weekday of that month: logs written from the recording then
carry a date of its month and its time of day instead of 1 January 1970."""

from __future__ import annotations

import re
from datetime import datetime, timedelta
from zoneinfo import ZoneInfo

WEEK_DAYS = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")
LOCAL_TIME = ZoneInfo("Europe/Berlin")  # highD was recorded near Cologne
NOTE = (
    "highD gives month, weekday and time of day: placed on the first such weekday of the month, Europe/Berlin"
)
_MONTH = re.compile(r"(\d{1,2})\.(\d{4})")
_TIME = re.compile(r"(\d{1,2}):(\d{2})")


def recording_start(month: object, week_day: object, start_time: object) -> datetime | None:
    """The local start of a recording from its recordingMeta fields, or None where any of them is
    missing or not of highD's form (the recording is read as before, its times from 0)."""
    m = _MONTH.fullmatch(str(month).strip()) if month is not None else None
    t = _TIME.fullmatch(str(start_time).strip()) if start_time is not None else None
    day = str(week_day).strip()[:3].title() if week_day is not None else ""
    if m is None or t is None or day not in WEEK_DAYS:
        return None
    month_no, year, hour, minute = int(m.group(1)), int(m.group(2)), int(t.group(1)), int(t.group(2))
    if not (1 <= month_no <= 12 and 1970 <= year <= 2200 and hour < 24 and minute < 60):
        return None
    first = datetime(year, month_no, 1, hour, minute, tzinfo=LOCAL_TIME)
    return first + timedelta(days=(WEEK_DAYS.index(day) - first.weekday()) % 7)


def start_ns(start: datetime) -> int:
    """Unix time of ``start`` in nanoseconds (what a drive log's clock counts)."""
    return int(start.timestamp()) * 1_000_000_000


def meta_fields(start: datetime) -> dict[str, str]:
    """``start`` as recordingMeta's ``month``, ``weekDay`` and ``startTime`` (what the simulator writes)."""
    local = start.astimezone(LOCAL_TIME)
    return {
        "month": f"{local.month:02d}.{local.year}",
        "weekDay": WEEK_DAYS[local.weekday()],
        "startTime": f"{local.hour:02d}:{local.minute:02d}",
    }
