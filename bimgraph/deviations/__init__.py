"""As-built deviations: each observed wall face measured against the plan, with its
uncertainty from the graph (`estimate`, `assess`), faces expected in view but never seen
(`visibility`), and the reports (`report`: JSON and CSV; `bcf`: BIM Collaboration Format)."""
