"""Results people can read (issue 34): values printed to the digits their errors resolve, a fit that prints as a
report (not an 11 kB dump), bundled protocols by name."""

from __future__ import annotations

import math
import re

import pandas as pd
import pytest

from conftest import PROTOCOL_DIR
from gyrorig._format import with_error
from gyrorig.cli import main
from gyrorig.fit import fit_angles
from gyrorig.protocols import BUNDLED_PROTOCOL_DIR, ProtocolError, bundled_protocols, load_protocol
from gyrorig.theory import predict
from test_fit import _noisy

CASES = [(1.7192, 8.7e-6), (98.05, 0.139), (4.725e-4, 3.1e-7), (12345.6, 78.0), (1234567.0, 2345.0), (0.5, 0.5),
         (-0.0123, 0.0045), (59.49, 0.0147), (1e-9, 3e-12), (-2.5e8, 1.5e3), (0.0, 0.013)]


def _parse(text: str) -> tuple[float, float, float]:
    """value, error and the place of the last printed digit of ``(v +- e)eN`` or ``v +- e``."""
    m = re.fullmatch(r"\(?(-?[\d.]+) \+- ([\d.]+)\)?(?:e([+-]\d+))?", text)
    assert m, text
    scale = 10.0 ** int(m.group(3) or 0)
    decimals = len(m.group(2).split(".")[1]) if "." in m.group(2) else 0
    return float(m.group(1)) * scale, float(m.group(2)) * scale, 10.0**-decimals * scale


@pytest.mark.parametrize("value,se", CASES)
def test_a_value_is_printed_to_the_digits_its_error_resolves(value, se):
    v, e, step = _parse(with_error(value, se))
    assert abs(v - value) <= 0.5 * step * (1 + 1e-9)
    assert abs(e - se) <= 0.5 * step * (1 + 1e-9)
    # two significant digits of the error: its last digit is 10-99 steps of the printed place
    assert 10 <= round(e / step) <= 100


def test_a_fit_prints_as_a_report_and_reprs_short():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, truth = _noisy(p, 2.0)
    fit = fit_angles(angles, p, prediction=predict(p, simulate_damping=False),
                     truth=truth[["t_s", "theta_rad", "phi_rad"]])
    text = str(fit)
    assert len(text) < 3000 and len(repr(fit)) < 400
    for name, q in fit.quantities.items():
        assert with_error(q.value, q.standard_error) in text, name
    assert 0.0 <= fit.p_value <= 1.0 and math.isfinite(fit.p_value)


def test_bundled_protocols_by_name(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the repository: the names must come with the package
    names = bundled_protocols()
    assert set(names) == {f.stem for f in BUNDLED_PROTOCOL_DIR.glob("*.toml")}
    for name in names:
        assert load_protocol(name).rig == load_protocol(BUNDLED_PROTOCOL_DIR / f"{name}.toml").rig
    assert main(["protocols"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert listed == list(names)
    with pytest.raises(ProtocolError):
        load_protocol("no-such-protocol")
    assert main(["theory", "free-top", "--no-simulate", "--json"]) == 0


def test_a_bundled_protocols_name_serves_identify_and_a_sweep(tmp_path, monkeypatch):
    """The commands that also read the protocol's text (identify writes it anew with the identified values, a sweep
    changes one key in it) take a bundled protocol's name as the others do (they looked for a file of that name)."""
    monkeypatch.chdir(tmp_path)
    table = tmp_path / "spin_down.csv"
    table.write_text("t (s),spin (rpm)\n0,4000\n30,3700\n60,3420\n90,3160\n120,2920\n150,2700\n")
    assert main(["-q", "identify", str(table), "--protocol", "air-cushion-heavy-top", "--out", "id"]) == 0
    assert load_protocol(tmp_path / "id" / "identified.toml").name == "air-cushion-heavy-top"
    assert main(["-q", "plan", "air-cushion-heavy-top", "--sweep", "camera.fps=100:200:2", "--out", "sweep"]) == 0
    assert len(pd.read_csv(tmp_path / "sweep" / "sweep_camera_fps.csv")) == 2


def test_theory_prints_predictions_to_the_digits_their_sd_resolves(tmp_path, capsys):
    from gyrorig.propagate import predict_with_uncertainty

    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    path = tmp_path / "p.toml"
    path.write_text(text.replace("mass_kg = 0.5292", "mass_kg = { value = 0.5292, sd = 0.002 }"))
    assert main(["theory", str(path), "--no-simulate"]) == 0
    out = capsys.readouterr().out
    entry = predict_with_uncertainty(load_protocol(path), simulate_damping=False)
    entry = entry.quantities["nutation_amplitude_rad"]
    assert with_error(entry.exact, entry.exact_sd) in out
