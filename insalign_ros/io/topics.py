"""Which topics of a bag hold the sensors: the ones the user names, else the contract's names, else found by type.

A driver's bag calls its topics what it likes (``/imu/data_raw``, ``/ublox/fix``, ``/vectornav/IMU``). When the
user names no topic, :func:`resolve_topics` takes, per sensor,

- the contract's topic (docs/bag_contract.md) when the bag has it with the right type;
- else the one topic of the sensor's type (flagged-sample siblings ``<topic>_invalid`` left out);
- none of the type: an error for the IMU (always needed); the GNSS fix and velocity are optional here (the caller
  decides: insalign-align needs a fix to initialise);

A named IMU topic the bag lacks, or one of another type, is an error; a named fix or velocity topic the bag lacks
is not read, with a warning (unless it is the contract's name, absent from many bags).
- several of the type: an error naming them for the IMU and the fix; for the optional velocity a warning, and
  none is read.

The truth is only ever taken by name (an odometry or pose topic in a real bag is another estimator, not truth).
Every error names what is missing and lists the bag's topics with their types (:func:`listing`).
"""

from __future__ import annotations

IMU_TYPE = "sensor_msgs/msg/Imu"
FIX_TYPE = "sensor_msgs/msg/NavSatFix"
VEL_TYPE = "geometry_msgs/msg/TwistWithCovarianceStamped"
INVALID_SUFFIX = "_invalid"

#: kind -> (message type, what it is, the insalign-align option that names it, needed)
SENSORS = {"imu": (IMU_TYPE, "IMU", "--imu-topic", True),
           "gps": (FIX_TYPE, "GNSS fix", "--gps-topic", False),
           "vel": (VEL_TYPE, "GNSS velocity", "--vel-topic", False)}
#: names that mean "do not read this optional sensor"
NONE_NAMES = ("", "none")


def listing(topics: dict) -> str:
    """'/a (type), /b (type)' in name order, or '(no topic)'."""
    return ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "(no topic)"


def resolve_topics(topics: dict, wanted: dict, defaults: dict, warnings: list | None = None) -> dict:
    """kind -> topic name (None: not read) for the kinds of :data:`SENSORS`.

    ``topics``: the bag's topic -> message type; ``wanted``: kind -> the name the user gave (None: find it;
    "none" or "": do not read an optional sensor); ``defaults``: kind -> the contract's name. Raises ValueError
    naming what is missing or ambiguous, with the bag's topics; a named optional topic that the bag lacks is not
    read (a warning unless it is the contract's name)."""
    warnings = [] if warnings is None else warnings
    out = {}
    for kind, (msgtype, what, option, needed) in SENSORS.items():
        name = wanted.get(kind)
        if name is not None and str(name).lower() in NONE_NAMES and not needed:
            out[kind] = None
        elif name is not None:
            if name not in topics and not needed:  # the contract's own name absent: normal; another: say so
                if name != defaults.get(kind):
                    warnings.append(f"no {what} topic {name!r} in the bag: none read; its topics: {listing(topics)}")
                out[kind] = None
                continue
            if name not in topics:
                raise ValueError(f"no {what} topic {name!r} ({option}) in the bag; its topics: {listing(topics)}")
            if topics[name] != msgtype:
                raise ValueError(f"{what} topic {name!r} is a {topics[name]}, not a {msgtype}; "
                                 f"the bag's topics: {listing(topics)}")
            out[kind] = name
        elif topics.get(defaults.get(kind)) == msgtype:
            out[kind] = defaults[kind]
        else:
            out[kind] = _by_type(topics, kind, warnings)
    return out


def _by_type(topics: dict, kind: str, warnings: list) -> str | None:
    msgtype, what, option, needed = SENSORS[kind]
    found = sorted(t for t, ty in topics.items() if ty == msgtype and not t.endswith(INVALID_SUFFIX))
    if len(found) == 1:
        return found[0]
    if not found:
        if needed:
            raise ValueError(f"no {what} topic: the bag has no {msgtype} (name one with {option}); its topics: "
                             f"{listing(topics)}")
        return None
    if kind == "vel":
        warnings.append(f"{len(found)} {msgtype} topics ({', '.join(found)}): no GNSS velocity read (name one with "
                        f"{option})")
        return None
    raise ValueError(f"{len(found)} {msgtype} topics ({', '.join(found)}): name the {what} topic with {option}; "
                     f"the bag's topics: {listing(topics)}")
