"""The measured-water files each data set of the model choice rests on (its results' inputs)."""

from __future__ import annotations

from pathlib import Path

from md.water.joint_data import JOINT_DATA_FILE

ROOT = Path(__file__).resolve().parents[1]

#: Per data set, the joint summaries and the measured g(r) it reads.
DATA_FILES = {
    "xray": [JOINT_DATA_FILE, ROOT / "md/water/data/skinner2013_gOO_295K_nm.csv"],
    "neutron": [JOINT_DATA_FILE, ROOT / "md/water/data/soper2013_gOO_gOH_gHH_nm.csv"],
}
