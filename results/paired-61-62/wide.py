"""`paired_equality.py record` with blur from step 0, the event loss ungated and the event response from step 0: the
host-syncs README's second pair. Usage: python wide.py PATH/TO/paired_equality.py OUT.json (dataset: ./pds)."""

import importlib.util
import sys
from pathlib import Path

script, out = Path(sys.argv[1]), Path(sys.argv[2])
spec = importlib.util.spec_from_file_location("paired_equality", script)
assert spec is not None and spec.loader is not None
module = importlib.util.module_from_spec(spec)
sys.modules["paired_equality"] = module
spec.loader.exec_module(module)
module.SMALL.update(blur_start_step=0, event_gate=False, event_crf_start_step=0)
module.record(module.Record(data=Path("pds"), out=out))
