"""Learning: the training data (:mod:`.training_data`), the learned model (:mod:`.model`) and its training (:mod:`.training`).

Above the reduced simulation, which training runs to measure held-out scenes.
"""
