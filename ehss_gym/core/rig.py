"""A servo rig: the plant's parameters, the controller's model of them and the valve's rated current, from a TOML file,
a dict or the figures of a datasheet.

A plant file is TOML. It gives the plant in one of two forms, and optionally the controller's model:

.. code-block:: toml

    name = "my rig"                 # optional: the name outputs show (default: the file's stem)
    about = "where the numbers come from"   # optional
    rated_current_mA = 10           # with a [plant] table: the valve's rated current, the loop's current limit
                                    # (optional, default 10 mA: Table I's loop)

    [plant]                         # the model's parameters in SI units (the fields of PlantParams) ...
    J = 0.05                        # kg*m^2
    # ... B, d_m, beta, V_m, c_d, rho, c_sm, P_s, K, tau (all eleven; the three numerical constants are optional)

    [datasheet]                     # ... or the figures a datasheet states, in the units their names carry
    rated_current_mA = 15
    rated_flow_lpm = 19             # at the rated current and the rated valve pressure drop below
    rated_valve_drop_bar = 70
    valve_bandwidth_hz = 60         # or valve_time_constant_s
    supply_pressure_bar = 140
    displacement_cm3_per_rev = 10
    inertia_kg_m2 = 0.015
    damping_Nms_per_rad = 0.05
    bulk_modulus_bar = 12000
    oil_volume_cm3 = 180            # or motor_volume_cm3 + line_length_m + line_bore_mm
    leakage_lpm = 0.2               # optional with leakage_at_bar (default: no leakage)
    leakage_at_bar = 140
    fluid_density_kg_m3 = 870       # optional (default 870)
    discharge_coefficient = 0.61    # optional (default 0.61)

    [model]                         # optional: the controller's model where it differs, SI (missing: the plant's)
    J = 0.02

The conversions (:func:`from_datasheet`) are derived in docs/MODEL.md, "From a datasheet to the model's parameters".
Every value is checked: a wrong type (text, a list), a value out of its range, a missing or unknown key, both or
neither of two alternatives; each error names the file, the table, the key, its unit and the accepted range.

Plain data (no numba, no simulator): the command line reads plant files without loading the kernels.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass, field

from .params import FIELDS, PlantParams
from .unmodelled import RATED_CURRENT
from .validate import check_number

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 (the dependency tomli is declared for it)
    import tomli as tomllib

PLANTS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "plants")
TABLE_I_NAME = "Table I"
RATED_CURRENT_RANGE = (0.0, 5000.0)  # [mA] accepted rated currents (servo valves 10..300 mA, proportional valves A)
NUMERICAL = ("delta_valve", "delta_friction", "dp_transition")  # PlantParams fields a [plant] table may leave out
PHYSICAL = tuple(f.name for f in FIELDS if f.name not in NUMERICAL)
TOP_KEYS = ("name", "about", "rated_current_mA", "plant", "datasheet", "model")
DEFAULT_DENSITY = 870.0  # [kg/m^3] mineral hydraulic oil (ISO VG 32-46) near 40 C
DEFAULT_DISCHARGE = 0.61  # [-] a sharp-edged orifice
LPM = 1.0 / 60000.0  # [m^3/s] per L/min
BAR = 1e5  # [Pa] per bar
CM3 = 1e-6  # [m^3] per cm^3


class PlantFileError(ValueError):
    """A plant file, dict or datasheet that cannot be used (the message names the file, table, key, unit, range)."""


@dataclass(frozen=True)
class Derived:
    """One model parameter derived from datasheet figures (for the outputs that show where a value came from).

    Attributes:
        field: the :class:`PlantParams` field.
        value: its value [unit].
        unit: its unit.
        formula: how it was computed, in the datasheet's names.
    """

    field: str
    value: float
    unit: str
    formula: str


@dataclass(frozen=True)
class Rig:
    """A servo rig: the true plant's nominal parameters, the controller's model of them and the valve's rated
    current. Two rigs are equal when these values are (the name and where they came from do not count).

    Attributes:
        plant: the plant's parameters (the nominal plant: random episodes draw their mismatch around it).
        model: the controller's model of the plant; None = the plant's own parameters.
        rated_current: the valve's rated current [mA]: the loop's current limit unless one is given, and the
            current the valve's threshold and hysteresis are percent of.
        name: the name outputs show.
        source: the file it was read from ("" = built in or given in Python).
        about: where the numbers come from (free text).
        derived: the parameters derived from a datasheet, with their formulas (empty for a [plant] table).
    """

    plant: PlantParams = field(default_factory=PlantParams)
    model: PlantParams | None = None
    rated_current: float = RATED_CURRENT
    name: str = field(default=TABLE_I_NAME, compare=False)
    source: str = field(default="", compare=False)
    about: str = field(default="", compare=False)
    derived: tuple = field(default=(), compare=False)

    def __post_init__(self):
        """Raises ValueError for a plant or model that is not a PlantParams or a bad rated current."""
        for name in ("plant", "model"):
            v = getattr(self, name)
            if not (isinstance(v, PlantParams) or (name == "model" and v is None)):
                raise ValueError(f"Rig.{name} must be a PlantParams{' or None' if name == 'model' else ''}, got "
                                 f"{type(v).__name__}")
        if self.model == self.plant:
            object.__setattr__(self, "model", None)  # one form for "the model is the plant"
        lo, hi = RATED_CURRENT_RANGE
        object.__setattr__(self, "rated_current", check_number("rated_current (the valve's rated current)",
                                                               self.rated_current, unit="mA", low=lo, high=hi,
                                                               low_open=True))
        for name in ("name", "source", "about"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"Rig.{name} must be a string, got {getattr(self, name)!r}")

    @property
    def controller_model(self) -> PlantParams:
        """The parameters the controller's model uses."""
        return self.plant if self.model is None else self.model

    @property
    def hash(self) -> str:
        """A short hash (8 hex digits) of the values (plant, model, rated current): two rigs with the same values share
        it whatever their names and files."""
        data = {"plant": [repr(v) for v in self.plant], "model": None if self.model is None else
                [repr(v) for v in self.model], "rated_current_mA": repr(self.rated_current)}
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:8]

    @property
    def is_table_i(self) -> bool:
        """The values are Table I's (the built-in plant, its model and the 10 mA rated current)."""
        return self == TABLE_I

    @property
    def label(self) -> str:
        """The rig as outputs name it: its name, its file and the hash of its values."""
        where = os.path.basename(self.source) if self.source else "built in"
        return f"{self.name} ({where}, #{self.hash})"

    def model_text(self) -> str:
        """The controller's model in words: the plant's parameters, or where it differs."""
        if self.model is None:
            return "the plant's parameters"
        diff = [f for f in PlantParams._fields if getattr(self.model, f) != getattr(self.plant, f)]
        return "differs from the plant in " + ", ".join(f"{f} = {getattr(self.model, f):g}" for f in diff)

    def summary(self) -> str:
        """One line for a command's summary: the plant and the controller's model."""
        return f"plant: {self.text()}"

    def text(self) -> str:
        """The rig in a sentence: its label, its rated current and the controller's model."""
        return f"{self.label}, rated current {self.rated_current:g} mA; controller's model: {self.model_text()}"

    def describe(self) -> dict:
        """The rig as plain data for a report, a CSV column or an NPZ: name, file, hash, values."""
        return {"name": self.name, "file": self.source, "hash": self.hash, "label": self.label,
                "rated_current_mA": self.rated_current, "plant": self.plant.as_dict(),
                "model": None if self.model is None else self.model.as_dict(), "model_text": self.model_text(),
                "derived": [dataclasses.asdict(d) for d in self.derived]}

    def as_dict(self) -> dict:
        """The rig in the form of a plant file with a [plant] table (JSON and TOML values): :func:`as_rig` reads it
        back to an equal rig (an exported policy records its plant so)."""
        out = {"name": self.name, "rated_current_mA": self.rated_current, "plant": self.plant.as_dict()}
        if self.about:
            out["about"] = self.about
        if self.model is not None:
            out["model"] = self.model.as_dict()
        return out

    def __str__(self) -> str:
        return self.label


TABLE_I = Rig()


# --- reading -------------------------------------------------------------------------------------------------


def _where(source: str, table: str | None = None) -> str:
    where = f"plant file {source}" if source else "plant"
    return where + (f", [{table}]" if table else "")


def _table(d: dict, key: str, source: str) -> dict | None:
    v = d.get(key)
    if v is not None and not isinstance(v, dict):
        raise PlantFileError(f"{_where(source)}: {key} must be a table ([{key}] in TOML, a dict in Python), got "
                             f"{type(v).__name__}")
    return v


def _check_keys(d: dict, valid, where: str) -> None:
    bad = sorted(str(k) for k in d if k not in valid)
    if bad:
        raise PlantFileError(f"{where}: unknown key(s) {bad}; valid: {', '.join(valid)}")


def _params(values: dict, base: PlantParams | None, where: str) -> PlantParams:
    """PlantParams from a [plant] or [model] table (SI); ``base`` None: every physical field is required."""
    _check_keys(values, PlantParams._fields, where)
    if base is None:
        missing = [k for k in PHYSICAL if k not in values]
        if missing:
            raise PlantFileError(f"{where}: missing key(s) {missing}; a [plant] table gives all of "
                                 f"{', '.join(PHYSICAL)} in SI units (the model's parameters; docs/MODEL.md)")
        base = PlantParams()
    try:
        return dataclasses.replace(base, **values)
    except ValueError as exc:
        raise PlantFileError(f"{where}: {exc}") from None


def rig_from_dict(data: dict, *, source: str = "", name: str | None = None) -> Rig:
    """A :class:`Rig` from a plant file's content (the structure of the module docstring).

    Args:
        data: the file's tables and keys; a flat dict of :class:`PlantParams` fields is read as a [plant] table.
        source: the file it came from (for errors and outputs).
        name: the name when ``data`` gives none (default: the file's stem, else "custom plant").

    Raises:
        PlantFileError: anything the module docstring lists.
    """
    if not isinstance(data, dict):
        raise PlantFileError(f"{_where(source)} must be a table of keys, got {type(data).__name__}")
    if data and set(data) <= set(PlantParams._fields):
        data = {"plant": data}
    _check_keys(data, TOP_KEYS, _where(source))
    plant_t, sheet_t, model_t = (_table(data, k, source) for k in ("plant", "datasheet", "model"))
    if (plant_t is None) == (sheet_t is None):
        raise PlantFileError(f"{_where(source)}: give the plant either as a [plant] table (the model's parameters, SI) "
                             f"or as a [datasheet] table, {'not both' if plant_t is not None else 'got neither'}")
    derived: tuple = ()
    if sheet_t is not None:
        if "rated_current_mA" in data:
            raise PlantFileError(f"{_where(source)}: rated_current_mA belongs in [datasheet] when the plant is a "
                                 "datasheet")
        plant, rated, derived = from_datasheet(sheet_t, where=_where(source, "datasheet"))
    else:
        rated = data.get("rated_current_mA", RATED_CURRENT)
        plant = _params(plant_t, None, _where(source, "plant"))
    model = None if model_t is None else _params(model_t, plant, _where(source, "model"))
    stem = os.path.splitext(os.path.basename(source))[0] if source else "custom plant"
    label = data.get("name", name or stem)
    about = data.get("about", "")
    for key, v in (("name", label), ("about", about)):
        if not isinstance(v, str):
            raise PlantFileError(f"{_where(source)}: {key} must be a string, got {v!r}")
    try:
        return Rig(plant=plant, model=model, rated_current=rated, name=label, source=source, about=about,
                   derived=derived)
    except ValueError as exc:
        raise PlantFileError(f"{_where(source)}: {exc}") from None


def load_rig(path: str | os.PathLike) -> Rig:
    """A :class:`Rig` from a TOML plant file.

    Raises:
        PlantFileError: a missing or unreadable file, TOML that does not parse, or content that
            :func:`rig_from_dict` refuses.
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise PlantFileError(f"plant file {path}: file not found; give a TOML plant file (docs: 'Your own servo') "
                             f"or a shipped plant: {', '.join(shipped_plants())}") from None
    except OSError as exc:
        raise PlantFileError(f"plant file {path}: cannot read it ({exc.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PlantFileError(f"plant file {path}: not valid TOML ({exc})") from None
    return rig_from_dict(data, source=path)


def shipped_plants() -> dict[str, str]:
    """The plant files shipped with the package: name -> path (``ehss_gym/plants/<name>.toml``)."""
    try:
        files = sorted(f for f in os.listdir(PLANTS_DIR) if f.endswith(".toml"))
    except OSError:
        return {}
    return {f[:-5]: os.path.join(PLANTS_DIR, f) for f in files}


def as_rig(value) -> Rig:
    """The rig a ``plant`` setting names.

    Args:
        value: None (Table I), a :class:`Rig`, a :class:`PlantParams` (the plant; its own model, a 10 mA rated
            current), a dict (a plant file's content, or the fields of PlantParams), a TOML file path, or the name
            of a shipped plant (:func:`shipped_plants`).

    Raises:
        PlantFileError: a value of another type, or a file or dict that cannot be used.
    """
    if value is None:
        return TABLE_I
    if isinstance(value, Rig):
        return value
    if isinstance(value, PlantParams):
        return Rig(plant=value, name="custom plant")
    if isinstance(value, dict):
        return rig_from_dict(value)
    if isinstance(value, (str, os.PathLike)):
        path = os.fspath(value)
        shipped = shipped_plants()
        if path in shipped and not os.path.exists(path):
            path = shipped[path]
        return load_rig(path)
    raise PlantFileError(f"plant must be a TOML file path, a shipped plant name ({', '.join(shipped_plants())}), a "
                         f"dict, a PlantParams or a Rig, got {type(value).__name__}")


# --- the datasheet ----------------------------------------------------------------------------------------------

# key: (unit, what it is, low, high, low_open); the unit is also in the key's name
SHEET = {
    "rated_current_mA": ("mA", "the valve's rated current", *RATED_CURRENT_RANGE, True),
    "rated_flow_lpm": ("L/min", "rated flow at the rated current and the rated valve drop", 0.0, 1e4, True),
    "rated_valve_drop_bar": ("bar", "valve pressure drop of the rated flow (both metering edges)", 0.0, 1e3, True),
    "valve_time_constant_s": ("s", "the valve's first-order time constant", 1e-5, 1.0, False),
    "valve_bandwidth_hz": ("Hz", "the valve's -3 dB frequency", 0.1, 1e4, False),
    "supply_pressure_bar": ("bar", "supply pressure", 1.0, 1e3, False),
    "displacement_cm3_per_rev": ("cm^3/rev", "motor displacement per revolution", 0.0, 1e5, True),
    "inertia_kg_m2": ("kg*m^2", "inertia of motor and load", 0.0, 1e3, True),
    "damping_Nms_per_rad": ("N*m*s/rad", "viscous damping", 0.0, 1e4, False),
    "bulk_modulus_bar": ("bar", "effective bulk modulus of the oil", 100.0, 1e5, False),
    "oil_volume_cm3": ("cm^3", "oil volume under compression (both motor chambers and both lines)", 0.0, 1e6, True),
    "motor_volume_cm3": ("cm^3", "the motor's internal volume (both chambers)", 0.0, 1e6, False),
    "line_length_m": ("m", "length of each of the two lines between valve and motor", 0.0, 1e3, False),
    "line_bore_mm": ("mm", "inner diameter of the lines", 0.0, 1e3, True),
    "leakage_lpm": ("L/min", "the motor's internal leakage flow", 0.0, 1e3, False),
    "leakage_at_bar": ("bar", "load pressure of the leakage figure", 0.0, 1e3, True),
    "fluid_density_kg_m3": ("kg/m^3", "fluid density", 500.0, 2000.0, False),
    "discharge_coefficient": ("-", "valve discharge coefficient", 0.0, 1.0, True),
}
SHEET_REQUIRED = ("rated_current_mA", "rated_flow_lpm", "rated_valve_drop_bar", "supply_pressure_bar",
                  "displacement_cm3_per_rev", "inertia_kg_m2", "damping_Nms_per_rad", "bulk_modulus_bar")
# (alternative A, alternative B): exactly one of them
SHEET_ONE_OF = ((("valve_time_constant_s",), ("valve_bandwidth_hz",)),
                (("oil_volume_cm3",), ("motor_volume_cm3", "line_length_m", "line_bore_mm")))


def _sheet_values(sheet: dict, where: str) -> dict:
    """The datasheet's values, each checked (type, unit, range), and its structure (required keys, alternatives)."""
    _check_keys(sheet, tuple(SHEET), where)
    missing = [k for k in SHEET_REQUIRED if k not in sheet]
    if missing:
        raise PlantFileError(f"{where}: missing key(s) {missing}")
    for a, b in SHEET_ONE_OF:
        has_a, has_b = any(k in sheet for k in a), any(k in sheet for k in b)
        if has_a == has_b:
            raise PlantFileError(f"{where}: give {' + '.join(a)} or {' + '.join(b)}, "
                                 f"{'not both' if has_a else 'got neither'}")
        group = a if has_a else b
        if not all(k in sheet for k in group):
            missing = [k for k in group if k not in sheet]
            raise PlantFileError(f"{where}: {' + '.join(group)} go together; missing {missing}")
    if ("leakage_lpm" in sheet) != ("leakage_at_bar" in sheet):
        raise PlantFileError(f"{where}: leakage_lpm and leakage_at_bar go together (the leakage flow and the load "
                             "pressure it was measured at)")
    out = {}
    for k, v in sheet.items():
        unit, text, lo, hi, lo_open = SHEET[k]
        try:
            out[k] = check_number(f"{k} ({text})", v, unit=unit, low=lo, high=hi, low_open=lo_open)
        except ValueError as exc:
            raise PlantFileError(f"{where}: {exc}") from None
    return out


def from_datasheet(sheet: dict, *, where: str = "datasheet") -> tuple[PlantParams, float, tuple[Derived, ...]]:
    """The model's parameters from datasheet figures (docs/MODEL.md, "From a datasheet to the model's parameters").

    Args:
        sheet: the [datasheet] table (keys of :data:`SHEET`, units in their names).
        where: how errors name the table.

    Returns:
        (the plant's parameters, the rated current [mA], the derivation of each parameter).

    Raises:
        PlantFileError: see the module docstring.
    """
    s = _sheet_values(sheet, where)
    rho = s.get("fluid_density_kg_m3", DEFAULT_DENSITY)
    c_d = s.get("discharge_coefficient", DEFAULT_DISCHARGE)
    i_r = s["rated_current_mA"]
    rows = [
        # the orifice Q = c_d x4 sqrt(dp/rho) at the steady opening x4 = K I_r and the rated drop gives the rated flow
        ("K", s["rated_flow_lpm"] * LPM / (c_d * i_r * math.sqrt(s["rated_valve_drop_bar"] * BAR / rho)), "m^2/mA",
         "Q_r / (c_d I_r sqrt(dp_r / rho))"),
        ("tau", s["valve_time_constant_s"] if "valve_time_constant_s" in s else
         1.0 / (2.0 * math.pi * s["valve_bandwidth_hz"]), "s",
         "valve_time_constant_s" if "valve_time_constant_s" in s else "1 / (2 pi f_-3dB)"),
        ("P_s", s["supply_pressure_bar"] * BAR, "Pa", "supply_pressure_bar * 1e5"),
        ("d_m", s["displacement_cm3_per_rev"] * CM3 / (2.0 * math.pi), "m^3/rad", "D [cm^3/rev] * 1e-6 / (2 pi)"),
        ("J", s["inertia_kg_m2"], "kg*m^2", "inertia_kg_m2"),
        ("B", s["damping_Nms_per_rad"], "N*m*s/rad", "damping_Nms_per_rad"),
        ("beta", s["bulk_modulus_bar"] * BAR, "Pa", "bulk_modulus_bar * 1e5"),
        ("V_m", s["oil_volume_cm3"] * CM3 if "oil_volume_cm3" in s else
         s["motor_volume_cm3"] * CM3 + 2.0 * s["line_length_m"] * math.pi * (s["line_bore_mm"] * 1e-3) ** 2 / 4.0,
         "m^3", "oil_volume_cm3 * 1e-6" if "oil_volume_cm3" in s else "V_motor + 2 L pi d^2 / 4"),
        ("c_sm", s["leakage_lpm"] * LPM / (s["leakage_at_bar"] * BAR) if "leakage_lpm" in s else 0.0, "m^5/(N*s)",
         "Q_leak / p_leak" if "leakage_lpm" in s else "0 (no leakage given)"),
        ("rho", rho, "kg/m^3", "fluid_density_kg_m3" if "fluid_density_kg_m3" in s else
         f"{DEFAULT_DENSITY:g} (default)"),
        ("c_d", c_d, "-", "discharge_coefficient" if "discharge_coefficient" in s else
         f"{DEFAULT_DISCHARGE:g} (default)"),
    ]
    try:
        plant = PlantParams(**{name: v for name, v, _, _ in rows})
    except ValueError as exc:
        raise PlantFileError(f"{where}: the figures give a model parameter out of its range: {exc}") from None
    return plant, i_r, tuple(Derived(name, v, unit, formula) for name, v, unit, formula in rows)


__all__ = ["Rig", "TABLE_I", "Derived", "PlantFileError", "load_rig", "rig_from_dict", "as_rig", "from_datasheet",
           "shipped_plants", "SHEET", "SHEET_REQUIRED", "PHYSICAL", "PLANTS_DIR"]
