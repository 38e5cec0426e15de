"""Prints every scalar in a TensorBoard log directory as JSON {tag: [[step, value], ...]}, read
with TensorBoard's own EventAccumulator (which also drops what a restart superseded)."""
import json
import sys

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

acc = EventAccumulator(sys.argv[1], size_guidance={"scalars": 0})
acc.Reload()
print(json.dumps({tag: [[e.step, e.value] for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}))
