"""Documents for people: the evaluation report (report.md, report.html), the ablation and explain pages."""
