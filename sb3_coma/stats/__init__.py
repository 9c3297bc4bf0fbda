"""Results of evaluations, compared and tabled: paired statistics on shared missions (:mod:`.paired`)
and Table-I style tables (:mod:`.tables`). Reads ``EvaluationResult`` s; runs nothing."""
