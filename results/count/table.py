"""outputs/count/<scene>/count-<run>-<source>/count.json -> the Markdown table of results/count/README.md (stdout)."""

import json
from pathlib import Path

print(
    "| scene | run | detector on | counted | visible truth | count error | precision | recall | F1 | mean match error (m) | detections | depth spread |"
)
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for path in sorted(Path("outputs/count").glob("*/count-*/count.json")):
    r = json.loads(path.read_text())
    s = r["score"]
    _, run, source = path.parent.name.split("-", 2)
    print(
        f"| {path.parent.parent.name} | {run} | {source} | {s['counted']} | {s['visible']} | {s['count_error']:+.0%} | "
        f"{s['precision']:.2f} | {s['recall']:.2f} | {s['f1']:.2f} | {s['mean_match_error']:.3f} | {r['detections']} | "
        f"{r.get('depth_spread', float('nan')):.3f} |"
    )
