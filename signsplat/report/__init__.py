"""The HTML metric report: gather every stage's tables (:mod:`.collect`), draw the figures
(:mod:`.plots`), write a self-contained ``reports/index.html`` (:mod:`.html`), and summarise the
ablation and sweep runs (:mod:`.runs`). ``signsplat report --help`` is the entry point."""
