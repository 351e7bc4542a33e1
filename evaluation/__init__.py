"""Evaluation above the MPC core: closed-loop trials and their records, paired comparison,
the accuracy-against-success study, planner-visited data (improve), diagnostics pooled over
trials."""
