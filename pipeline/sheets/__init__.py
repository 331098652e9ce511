"""Contact sheets and previews of every stage, in one place (reads every stage's outputs)."""
