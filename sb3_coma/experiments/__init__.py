"""The experiments: the studies behind the paper's tables, figures and the verdicts in docs/."""
