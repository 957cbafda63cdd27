"""Reading finished runs: learning-curve plots, the per-experiment reports (table.py: final
returns and samples to TRPO's final; aggregate.py: IQM and probability of improvement;
aggregate_report.py: their reading of a sweep's curves; report.py: the figures and tables of a
sweep), deterministic evaluation (and video), the gradient error."""
