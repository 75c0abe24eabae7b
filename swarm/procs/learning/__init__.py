"""The processes of learning in the field: the learner and the rollout workers."""
