"""Reports: Markdown, figures, summary.json and rerun recordings of every study."""
