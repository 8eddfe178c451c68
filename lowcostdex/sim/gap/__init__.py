"""Reality-gap analysis: show what the simulation gets wrong, name the cause, extend the model,
measure the gain (issue 6). See docs/gap_analysis.md."""
