"""Regenerate the assets shipped in src/dano/data from ../shared/data (run from the repo root)."""

from pathlib import Path

import dano
from dano.asset import save
from dano.io import load_paper_collider

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
OUT = Path(__file__).resolve().parents[1] / "src" / "dano" / "data"

if __name__ == "__main__":
    bunny = load_paper_collider(SHARED / "dano" / "bunny.jld2", name="bunny")
    print(save(bunny, OUT / "bunny.dano"), dano.__version__)
