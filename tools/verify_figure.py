"""Write docs/figures/verify.png: ``arsurf verify`` on a virtual session whose model has the wrong
pivot (arsurf.verify.virtual, seed 7), the figure at 110 dpi. Run from the repository root."""
from __future__ import annotations

import tempfile
from pathlib import Path

from arsurf.verify.verify import verify_session
from arsurf.verify.virtual import Case, run_experiment

ROOT = Path(__file__).resolve().parents[1]

if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        e = run_experiment(Case(seed=7, tip_radius=12e-9, drift_rate=0.1e-9, noise=0.2e-9, push_at=0.85, wrong="pivot"),
                           tmp)
        r = verify_session(e.session, e.after, out_dir=tmp, dpi=110)
        (ROOT / "docs" / "figures" / "verify.png").write_bytes(Path(r.files["figure"]).read_bytes())
        print(r.reasons)
