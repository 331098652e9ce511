"""Last stage: shards, manifest, verification (reads every earlier stage's outputs)."""
