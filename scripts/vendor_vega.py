"""Write ``.dvc/plots/offline.html``: DVC's page template with vega, vega-lite and vega-embed inlined,
so ``dvc plots show`` renders without the internet (DVC's own page loads them from a CDN).

    npm install --prefix /tmp/vega vega@5 vega-lite@5 vega-embed@6
    python scripts/vendor_vega.py /tmp/vega/node_modules

The three are BSD-3-Clause (University of Washington Interactive Data Lab); their licence and versions
go into the page's header comment. ``.dvc/config`` names the template (``plots.html_template``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / ".dvc" / "plots" / "offline.html"
PACKAGES = {"vega": "build/vega.min.js", "vega-lite": "build/vega-lite.min.js", "vega-embed": "build/vega-embed.min.js"}
PAGE = """<!DOCTYPE html>
<!-- boom-ik: DVC's plots page with its scripts inlined, so it renders offline (scripts/vendor_vega.py).
{notice}
-->
<html>
<head>
    <meta charset="utf-8">
    {refresh_tag}
    <title>boom-ik training curves (DVC plots)</title>
{scripts_inline}
    <style>
        body { font-family: sans-serif; }
        table { border-spacing: 15px; }
    </style>
</head>
<body>
    {plot_divs}
</body>
</html>
"""


def main(modules: Path) -> None:
    versions, scripts, licence = [], [], None
    for name, rel in PACKAGES.items():
        meta = json.loads((modules / name / "package.json").read_text())
        if meta.get("license") != "BSD-3-Clause":
            raise SystemExit(f"{name} {meta['version']}: licence {meta.get('license')!r}, not BSD-3-Clause")
        code = (modules / name / rel).read_text()
        if "</script" in code or any(p in code for p in ("{plot_divs}", "{scripts}", "{refresh_tag}")):
            raise SystemExit(f"{name}: its code holds a string that would break the page template")
        versions.append(f"{name} {meta['version']} ({meta['license']})")
        scripts.append(f"    <script>/* {name} {meta['version']} */\n{code}\n    </script>")
        if licence is None and (modules / name / "LICENSE").is_file():
            licence = (modules / name / "LICENSE").read_text()
    notice = "Inlined: " + ", ".join(versions) + ".\nLicence of all three:\n" + (licence or "").replace("--", "- -")
    page = PAGE.replace("{notice}", notice).replace("{scripts_inline}", "\n".join(scripts))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(page)
    print(f"{OUT.relative_to(ROOT)}: {OUT.stat().st_size / 1e3:.0f} kB, {', '.join(versions)}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("node_modules"))
