"""Plant files and datasheets (:mod:`ehss_gym.core.rig`) and the plant record's checks (:mod:`ehss_gym.core.params`):
the conversion against hand calculations written another way, the shipped files, and a table of bad inputs, each a
clear error naming the field."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ehss_gym.cli import main
from ehss_gym.core.params import FIELDS, PlantParams, make_plant_params
from ehss_gym.core.rig import (
    TABLE_I,
    PlantFileError,
    Rig,
    as_rig,
    from_datasheet,
    load_rig,
    rig_from_dict,
    shipped_plants,
)
from ehss_gym.core.signals import sine
from ehss_gym.core.sim import simulate
from ehss_gym.envs import EnvConfig, rollout

# the second shipped rig's datasheet, as its file gives it
COMPACT = {"rated_current_mA": 15, "rated_flow_lpm": 19, "rated_valve_drop_bar": 70, "valve_bandwidth_hz": 60,
           "supply_pressure_bar": 140, "displacement_cm3_per_rev": 10, "inertia_kg_m2": 0.015,
           "damping_Nms_per_rad": 0.05, "bulk_modulus_bar": 12000, "motor_volume_cm3": 25, "line_length_m": 1.0,
           "line_bore_mm": 10, "leakage_lpm": 0.2, "leakage_at_bar": 140, "fluid_density_kg_m3": 870}
TABLE_I_SI = {f.name: getattr(PlantParams(), f.name) for f in FIELDS[:11]}


def _toml(d: dict) -> str:
    """A minimal TOML writer for the tests' files (top-level keys, then one level of tables)."""
    def val(v):
        return f'"{v}"' if isinstance(v, str) else ("true" if v is True else repr(v))
    lines = [f"{k} = {val(v)}" for k, v in d.items() if not isinstance(v, dict)]
    for k, v in d.items():
        if isinstance(v, dict):
            lines += [f"[{k}]"] + [f"{kk} = {val(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


# --- the conversion, checked another way -----------------------------------------------------------------------


def test_valve_gain_matches_the_orifice_equation_written_per_metering_edge():
    """K from the rated flow, against the orifice equation of one metering edge: the rated valve drop splits evenly
    over the two edges, each passes Q_r = C_d A sqrt(2 dp_edge / rho) at the rated opening A = K I_r."""
    plant, rated, _ = from_datasheet(COMPACT)
    dp_edge = 70e5 / 2.0  # [Pa] 35 bar per edge
    q_r = 19.0 / 1000.0 / 60.0  # [m^3/s]
    area = q_r / (0.61 * math.sqrt(2.0 * dp_edge / 870.0))  # [m^2] the opening at the rated current
    assert rated == 15.0
    assert plant.K == pytest.approx(area / 15.0, rel=1e-12)
    # the datasheet's own rule for another drop, Q = Q_r sqrt(dp / dp_r), from the model's flow at no load
    dp = 140e5
    q_model = plant.c_d * plant.K * rated * math.sqrt(dp / plant.rho)
    assert q_model == pytest.approx(q_r * math.sqrt(dp / 70e5), rel=1e-12)


def test_the_other_figures_against_hand_calculations():
    plant, _, derived = from_datasheet(COMPACT)
    assert plant.d_m * 2.0 * math.pi * 1e6 == pytest.approx(10.0, rel=1e-12)  # back to cm^3/rev
    line = math.pi * 0.005**2 * 1.0  # [m^3] one line of 1 m and 10 mm bore
    assert plant.V_m == pytest.approx(25e-6 + 2.0 * line, rel=1e-12)
    assert plant.tau == pytest.approx(1.0 / (2.0 * math.pi * 60.0), rel=1e-12)
    # leakage 0.2 L/min at 140 bar: c_sm * p = Q
    assert plant.c_sm * 140e5 * 60000.0 == pytest.approx(0.2, rel=1e-12)
    assert (plant.P_s, plant.beta, plant.J, plant.B) == (140e5, 12000e5, 0.015, 0.05)
    assert {d.field for d in derived} == {f.name for f in FIELDS[:11]}


def test_a_datasheet_rig_runs_at_the_speed_its_rated_flow_and_displacement_give():
    """The whole simulator, from the file's figures: at the rated current, the supply equal to the rated valve drop,
    no damping and no leakage, the motor runs where all the rated flow passes it: rpm = (L/min) / (cm^3/rev)."""
    sheet = {**COMPACT, "supply_pressure_bar": 70, "damping_Nms_per_rad": 0.0}
    sheet.pop("leakage_lpm"), sheet.pop("leakage_at_bar")
    plant, rated, _ = from_datasheet(sheet)
    assert plant.B == 0.0 and plant.c_sm == 0.0

    class FullCurrent:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.ones((obs.shape[0], 1), dtype=np.float32), state

    episode = {"plant": plant, "model": None, "friction": (), "reference": sine(0.0, 1.0), "t_end": 3.0}
    res = rollout(FullCurrent(), {"task": "velocity", "mode": "direct", "current_limit": rated}, [episode],
                  trace=True)[0]
    omega = res.trace["y"][-1]  # [rad/s] the true output at the end
    rpm_hand = 19.0 / 10.0 * 1000.0  # 19 L/min through 10 cm^3/rev
    assert np.max(np.abs(res.trace["u"] - rated)) == 0.0  # the rated current, held
    assert omega * 60.0 / (2.0 * math.pi) == pytest.approx(rpm_hand, rel=1e-6)


def test_the_table_i_file_is_table_i_and_its_datasheet_form_converts_back():
    rig = load_rig(shipped_plants()["table1"])
    assert rig == TABLE_I and rig.plant == PlantParams() and rig.rated_current == 10.0 and rig.is_table_i
    assert as_rig(None) is TABLE_I and as_rig("table1") == TABLE_I
    # the file's commented datasheet form (its figures rounded to 4-5 digits)
    sheet = {"rated_current_mA": 10, "rated_flow_lpm": 25.822, "rated_valve_drop_bar": 70,
             "valve_time_constant_s": 0.01, "supply_pressure_bar": 90, "displacement_cm3_per_rev": 18.85,
             "inertia_kg_m2": 0.05, "damping_Nms_per_rad": 0.2, "bulk_modulus_bar": 8000, "oil_volume_cm3": 300,
             "leakage_lpm": 0.486, "leakage_at_bar": 90, "fluid_density_kg_m3": 900}
    plant, rated, _ = from_datasheet(sheet)
    for f in FIELDS:
        assert getattr(plant, f.name) == pytest.approx(getattr(PlantParams(), f.name), rel=1e-4), f.name


def test_the_second_shipped_rig_differs_from_table_i_in_every_datasheet_figure():
    rig = as_rig("compact140")
    assert rig.rated_current != TABLE_I.rated_current and rig.hash != TABLE_I.hash
    for name in ("J", "B", "d_m", "beta", "V_m", "rho", "c_sm", "P_s", "K", "tau"):
        assert getattr(rig.plant, name) != getattr(PlantParams(), name), name
    assert rig.plant == from_datasheet(COMPACT)[0]
    assert "Moog" in rig.about and rig.label.startswith("compact 140 bar rig (compact140.toml, #")


# --- the record, every route ------------------------------------------------------------------------------------


def test_every_construction_path_checks_the_values():
    for make in (lambda: PlantParams(J="0.05"), lambda: make_plant_params(J="0.05"),
                 lambda: PlantParams().scaled(J=float("nan")), lambda: PlantParams().replace(J=0.0),
                 lambda: dataclasses.replace(PlantParams(), J=-1.0), lambda: Rig(plant=PlantParams(), rated_current=0)):
        with pytest.raises(ValueError, match=r"J \(total inertia|J factor|rated_current"):
            make()


def test_no_damping_and_no_leakage_are_accepted_and_the_loop_runs():
    """B = 0 and c_sm = 0 are physical (nothing divides by them); the env's default loop tracks on such a plant."""
    plant = PlantParams(B=0, c_sm=0.0)
    sc = EnvConfig.from_kwargs({"task": "velocity"}).template().replace(plant=plant, model=plant, t_end=2.0)
    m = simulate(sc).metrics()
    assert not m["diverged"] and not m["lost_track"] and m["rmse"] < 0.01


def test_a_rig_round_trips_through_its_dict_and_hashes_its_values_only():
    rig = as_rig("compact140")
    back = as_rig(rig.as_dict())
    assert back == rig and back.hash == rig.hash and back.name == rig.name
    assert dataclasses.replace(rig, name="other", source="") == rig  # names do not count
    model = as_rig({**rig.as_dict(), "model": {"J": 0.02}})
    assert model != rig and model.hash != rig.hash and model.controller_model.J == 0.02
    assert model.model_text() == "differs from the plant in J = 0.02"
    assert as_rig(TABLE_I_SI) == TABLE_I  # a flat dict of the model's parameters
    assert as_rig(PlantParams(J=0.1)).plant.J == 0.1
    assert Rig(plant=PlantParams(), model=PlantParams()).model is None  # "the model is the plant", one form


# --- bad inputs: each a clear error naming the field ------------------------------------------------------------

GOOD_PLANT = {"name": "t", "rated_current_mA": 10, "plant": dict(TABLE_I_SI)}
GOOD_SHEET = {"datasheet": dict(COMPACT)}


def _with(base: dict, table: str | None, **changes) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    target = out if table is None else out[table]
    for k, v in changes.items():
        if v is _DROP:
            target.pop(k)
        else:
            target[k] = v
    return out


_DROP = object()
BAD_VALUES = [  # (what, a callable that must raise, the pattern its message must hold)
    ("a string inertia", lambda: PlantParams(J="0.02"), r"J \(total inertia of motor and load\) \[kg\*m\^2\].*'0.02'"),
    ("zero supply", lambda: PlantParams(P_s=0.0), r"P_s \(supply pressure\) \[Pa\] .*\[100000, 1e\+08\]"),
    ("supply in bar", lambda: PlantParams(P_s=210.0), r"P_s \(supply pressure\) \[Pa\].*got 210"),
    ("negative damping", lambda: PlantParams(B=-0.1), r"B \(viscous damping coefficient\) \[N\*m\*s/rad\] .*\[0, "),
    ("NaN leakage", lambda: PlantParams(c_sm=float("nan")), r"c_sm \(motor leakage coefficient\)"),
    ("zero time constant", lambda: PlantParams(tau=0.0), r"tau \(servo-valve time constant\) \[s\]"),
    ("a bool valve gain", lambda: PlantParams(K=True), r"K \(servo-valve gain.*\[m\^2/mA\].*True \(a bool\)"),
    ("displacement per rev", lambda: PlantParams(d_m=18.85), r"d_m \(motor displacement per radian\) \[m\^3/rad\]"),
    ("volume in cm^3", lambda: make_plant_params(V_m=300.0), r"V_m \(oil volume.*\[m\^3\].*got 300"),
    ("a list density", lambda: PlantParams(rho=[900.0]), r"rho \(fluid density\) \[kg/m\^3\]"),
    ("a negative mismatch", lambda: PlantParams().scaled(J=-1.0), r"^J factor must be"),
    ("an unknown name", lambda: make_plant_params(Jm=1.0), r"unknown plant parameter 'Jm'"),
    ("a plant of another type", lambda: as_rig(42), r"plant must be a TOML file path"),
]
BAD_FILES = [  # (what, file content or raw text, the pattern its message must hold)
    ("not TOML", "J = = 1\n", r"not valid TOML"),
    ("both forms", {**GOOD_PLANT, **GOOD_SHEET}, r"either as a \[plant\] table .* not both"),
    ("neither form", {"name": "x"}, r"got neither"),
    ("a missing model parameter", _with(GOOD_PLANT, "plant", tau=_DROP), r"\[plant\]: missing key\(s\) \['tau'\]"),
    ("an unknown model parameter", _with(GOOD_PLANT, "plant", Jm=1.0), r"\[plant\]: unknown key\(s\) \['Jm'\]"),
    ("a pressure as text", _with(GOOD_PLANT, "plant", P_s="90 bar"), r"\[plant\]: P_s \(supply pressure\) \[Pa\]"),
    ("a negative damping", _with(GOOD_PLANT, "plant", B=-1.0), r"\[plant\]: B \(viscous damping"),
    ("a zero rated current", _with(GOOD_PLANT, None, rated_current_mA=0), r"rated_current .*\[mA\] .*\(0, 5000\]"),
    ("an unknown table", {**GOOD_PLANT, "plnat": {}}, r"unknown key\(s\) \['plnat'\]"),
    ("a name that is a number", _with(GOOD_PLANT, None, name=5), r"name must be a string"),
    ("a bad model value", {**GOOD_PLANT, "model": {"J": 0.0}}, r"\[model\]: J \(total inertia"),
    ("an unknown model key", {**GOOD_PLANT, "model": {"inertia": 0.1}}, r"\[model\]: unknown key\(s\) \['inertia'\]"),
    ("a negative rated flow", _with(GOOD_SHEET, "datasheet", rated_flow_lpm=-5),
     r"\[datasheet\]: rated_flow_lpm \(rated flow.*\) \[L/min\] .*\(0, 10000\]"),
    ("a flow as text", _with(GOOD_SHEET, "datasheet", rated_flow_lpm="19 L/min"), r"rated_flow_lpm .*'19 L/min'"),
    ("a missing rated current", _with(GOOD_SHEET, "datasheet", rated_current_mA=_DROP),
     r"\[datasheet\]: missing key\(s\) \['rated_current_mA'\]"),
    ("two valve dynamics", _with(GOOD_SHEET, "datasheet", valve_time_constant_s=0.003),
     r"valve_time_constant_s or valve_bandwidth_hz, not both"),
    ("no valve dynamics", _with(GOOD_SHEET, "datasheet", valve_bandwidth_hz=_DROP), r"got neither"),
    ("half of the line figures", _with(GOOD_SHEET, "datasheet", line_bore_mm=_DROP), r"go together.*line_bore_mm"),
    ("leakage without its pressure", _with(GOOD_SHEET, "datasheet", leakage_at_bar=_DROP),
     r"leakage_lpm and leakage_at_bar go together"),
    ("a bulk modulus in GPa", _with(GOOD_SHEET, "datasheet", bulk_modulus_bar=1.2),
     r"bulk_modulus_bar \(effective bulk modulus of the oil\) \[bar\] .*\[100, 100000\]"),
    ("a bandwidth of a slow valve", _with(GOOD_SHEET, "datasheet", valve_bandwidth_hz=0.1),
     r"the figures give a model parameter out of its range: tau \(servo-valve time constant\) \[s\]"),
    ("a misspelt datasheet key", _with(GOOD_SHEET, "datasheet", displacement_cm3=10),
     r"\[datasheet\]: unknown key\(s\) \['displacement_cm3'\]"),
    ("a rated current outside the datasheet", {**GOOD_SHEET, "rated_current_mA": 15},
     r"rated_current_mA belongs in \[datasheet\]"),
]


@pytest.mark.parametrize("what, make, pattern", BAD_VALUES, ids=[b[0] for b in BAD_VALUES])
def test_a_bad_value_is_a_clear_error_naming_the_field(what, make, pattern):
    with pytest.raises(ValueError, match=pattern):
        make()


@pytest.mark.parametrize("what, content, pattern", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_a_bad_plant_file_is_a_clear_error_naming_the_file_and_the_key(what, content, pattern, tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(content if isinstance(content, str) else _toml(content))
    with pytest.raises(PlantFileError, match=pattern) as err:
        load_rig(path)
    assert str(path) in str(err.value)
    if not isinstance(content, str):  # the same content given as a dict
        with pytest.raises(PlantFileError, match=pattern):
            rig_from_dict(content)


def test_a_missing_file_names_the_shipped_plants(tmp_path):
    with pytest.raises(PlantFileError, match=r"file not found; .* shipped plant: compact140, table1"):
        as_rig(str(tmp_path / "nothere.toml"))


def test_there_are_twenty_bad_inputs_at_least():
    assert len(BAD_VALUES) + len(BAD_FILES) >= 20


def test_the_plant_command_prints_the_parameters_and_refuses_a_bad_file(tmp_path, capsys):
    assert main(["plant", "compact140"]) == 0
    out = capsys.readouterr().out
    assert "compact 140 bar rig (compact140.toml, #" in out and "Q_r / (c_d I_r sqrt(dp_r / rho))" in out
    bad = tmp_path / "bad.toml"
    bad.write_text(_toml(_with(GOOD_SHEET, "datasheet", rated_flow_lpm=-5)))
    with pytest.raises(SystemExit) as exc:
        main(["plant", str(bad)])
    assert exc.value.code == 2 and "rated_flow_lpm" in capsys.readouterr().err
