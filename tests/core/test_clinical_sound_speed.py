"""With the fluid's stabilisation that does not grow with c (``hyperviscosity_speed`` 15 m/s,
``hyperviscosity_divergence`` 0.5; docs/model.md section 4) the clinical preset does not depend
on the artificial sound speed (issue 25; docs/validation.md, "A stabilisation that does not grow
with c"): from c0 = 10 to 20 and 40 m/s (c_slope = 2 c0) P1 and P2 move by less than 0.2 mmHg,
CH by less than 0.3 mmHg and DA by less than 0.01 mm, at coarse resolution (measured at IOP 16:
0.02, 0.10, 0.11 mmHg, 0.005 mm; with the preset's stabilisation growing with c P2 moves by 3.6
mmHg there).  Paper resolution is the study's, ``python -m studies.clinical_sound_speed``.

IOP 10 mmHg is not in this test: at coarse resolution its apex comes back to within 0.003-0.008/mm
of flat after the first convex crossing, so the second applanation's reading hangs on whether
the rebound crosses again (a question of the read-out, docs/validation.md), not on c."""

import pytest

from airpuff_core import RunParams, simulate

TOLERANCE = {"P1": 0.2, "P2": 0.2, "CH": 0.3, "DA": 0.01}


@pytest.mark.slow
@pytest.mark.parametrize("iop", [16.0, 25.0])
def test_clinical_metrics_do_not_move_with_the_sound_speed(iop):
    params = RunParams(model="clinical", thickness=0.54, IOP=iop, hyperviscosity_speed=15.0,
                       hyperviscosity_divergence=0.5)
    base = simulate(params).metrics
    for c0 in (20.0, 40.0):
        fast = simulate(params.replace(c0=c0, c_slope=2.0 * c0)).metrics
        for name, tolerance in TOLERANCE.items():
            assert abs(fast[name] - base[name]) < tolerance, (c0, name, base[name], fast[name])
