"""Write docs/images/michel_levy.png, the interference colours of docs/physics.md section 9:

    .venv/bin/python scripts/michel_levy.py
"""
from pathlib import Path

from mi_nest.views.plots import write_michel_levy_chart

if __name__ == "__main__":
    print(write_michel_levy_chart(Path(__file__).resolve().parents[1] / "docs" / "images" / "michel_levy.png"))
