"""The README's first two examples run as written, in a fresh interpreter that has done nothing
but ``import lobattodae as L`` (the test process has imported every submodule already, which
would hide a missing attribute such as ``L.examples``), and give the right answers."""

import json
import math
import pathlib
import re
import subprocess
import sys

from helpers import subprocess_env

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"

#: The sleigh's heading crosses 0.5 at t* with θ(t) = √(1 + I/(m a²)) (gd(k v_max t) − gd 0)
#: (README example: m = I = a = 1, v0 = 0, ω0 = 1, so E = 1, k = ½ and v_max = √2). The event is the
#: root of the dense output, whose error at rtol = 1e-8 (s = 3) is ~1e-6 in θ.
EVENT_TIME_TOL = 1e-5


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def _heading_crossing(theta: float) -> float:
    # θ = √2 gd(t/√2)  ⇒  t = √2 gd⁻¹(θ/√2),  gd⁻¹(x) = artanh(sin x)
    return math.sqrt(2.0) * math.atanh(math.sin(theta / math.sqrt(2.0)))


def test_readme_quick_start_and_variable_steps_examples_run_as_written():
    blocks = _python_blocks(README.read_text(encoding="utf-8"))
    assert len(blocks) >= 2 and "import lobattodae as L" in blocks[0] and "def heading" in blocks[1]
    check = """
import json
print("RESULT", json.dumps({
    "status": int(sol.result), "event": int(L.Result.EVENT), "t_event": float(sol.t_events[0][0]),
    "theta_event": float(sol.q_events[0][0][2]), "t_end": float(sol.t[-1]),
    "dense_q": [float(v) for v in sol.sol(0.3)[0]], "exact_q": [float(v) for v in ex.exact([0.3])[0][0]],
    "phi": float(sol.stats["max_constraint_residual"]),
}))
"""
    out = subprocess.run([sys.executable, "-c", blocks[0] + "\n" + blocks[1] + check], env=subprocess_env(),
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    (line,) = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    got = json.loads(line[len("RESULT "):])
    assert got["status"] == got["event"]
    t_star = _heading_crossing(0.5)
    assert abs(got["t_event"] - t_star) <= EVENT_TIME_TOL, (got["t_event"], t_star)
    assert got["t_end"] == got["t_event"]  # terminal: the run ends at the event
    # a terminal event ends with a step onto the located time: θ there is a step point's value,
    # 0.5 to the accuracy of the dense output the time was located on (§4 of variable-steps.md)
    assert abs(got["theta_event"] - 0.5) <= EVENT_TIME_TOL
    assert max(abs(a - b) for a, b in zip(got["dense_q"], got["exact_q"])) <= 1e-5
    assert got["phi"] <= 1e-13


def test_subpackages_are_attributes_after_a_bare_import():
    code = ("import lobattodae as L; pair = L.lobatto_pair(3); "
            "print(L.examples.chaplygin_sleigh().q0.shape, round(L.conditions.r_infinity(pair.a, pair.b), 12), "
            "'examples' in dir(L))")
    env = subprocess_env()
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split() == ["(3,)", "1.0", "True"]  # R(∞) = (−1)^(s−1)
    bad = subprocess.run([sys.executable, "-c", "import lobattodae as L; L.no_such_thing"], env=env,
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "has no attribute 'no_such_thing'" in bad.stderr
