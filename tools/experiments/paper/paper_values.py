"""The paper's printed numbers for Figs. 9, 11 and 13, each with the panel and case it belongs to.

Only numbers the paper prints are here, labelled as the paper labels them; what each can be
compared with (and what not) is decided by the figure builders and stated in the report.

* **Fig. 9** (caption): one demonstration case per row. Row 1: single sine, potential
  (stiffness-dominated) load, the most bent shape theta_1; row 2: three-term multisine,
  damping-dominated load, the near-flat shape theta_8. Panels (c)/(d): distributed pretension
  (eq 23), (e)/(f): averaged pretension (eq 25); each gives ``[N = 1, N = 10]`` RMSE [Nm].
  (The text says the N = 1 runs used a sine and the N = 10 runs a multisine; the caption
  assigns the excitation per row. We follow the caption: one run per row, both N on it.)
* **Fig. 11** (caption): panels (a)/(b) plot RMSE over all bending groups for stiffness- /
  damping-dominated outputs *without printed numbers*. Panel (c): theta_1 with stiff output,
  panel (d): theta_2 with damped output, each ``[this work, previous, Wu]`` RMSE [Nm] - single
  cases, not ranges. (The caption calls theta_1 "flat" and theta_2 "large bending"; Figs. 9
  and 10 call theta_1 the most bent group and theta_10 the flattest. Our theta_1 = 6.0 rad,
  theta_2 = 5.2 rad follow Figs. 9/10.)
* **Fig. 13(d)**: box plot of mean ``|tau_h|`` [Nm], "from left to right"
  ``[3.370, 0.642, 0.498, 1.334, 0.663]``. The boxes are not labelled in the text; the order
  uncompensated, (slow, high bending: PID+ff, LDO+ff), (fast, low bending: PID+ff, LDO+ff) is
  inferred from panels (a)-(c) and "LDO outperforms PID in fast motion" (1.334 vs 0.663). The
  uncompensated box does not say under which condition it was measured.
"""

from __future__ import annotations

#: Fig. 9 RMSE [Nm]: (case, pretension) -> (panel, (N = 1, N = 10)); case "bent" = row 1, "flat" = row 2
PAPER_FIG9: dict[tuple[str, str], tuple[str, tuple[float, float]]] = {
    ("bent", "distributed"): ("c", (1.2132, 0.3839)),
    ("flat", "distributed"): ("d", (0.5108, 0.4101)),
    ("bent", "averaged"): ("e", (0.4406, 0.5699)),
    ("flat", "averaged"): ("f", (0.3989, 0.3944)),
}

#: Fig. 9 demonstration cases: case -> (0-based routing group, excitation, output)
FIG9_CASES: dict[str, tuple[int, str, str]] = {"bent": (0, "sine", "stiff"), "flat": (7, "multisine", "damped")}

#: Fig. 11 single cases: panel -> (0-based routing group, output, {model: RMSE [Nm]})
PAPER_FIG11: dict[str, tuple[int, str, dict[str, float]]] = {
    "c": (0, "stiff", {"reduced": 0.3416, "single_sided": 0.9600, "wu": 1.1549}),
    "d": (1, "damped", {"reduced": 0.4366, "single_sided": 0.7461, "wu": 1.1245}),
}

#: Fig. 13(d), left to right: uncompensated (condition not stated), then per condition [Nm]
PAPER_FIG13_UNCOMPENSATED_NM = 3.370
PAPER_FIG13: dict[tuple[str, str], float] = {
    ("slow_high_bending", "pid_ff"): 0.642, ("slow_high_bending", "ldo_ff"): 0.498,
    ("fast_low_bending", "pid_ff"): 1.334, ("fast_low_bending", "ldo_ff"): 0.663,
}
