"""Estimators: Kalman steps (``kalman``), the particle filter (``particle`` and its parts
``particle_move``, ``particle_weight_update``, ``particle_resampling`` and
``particle_estimate``; the cloud in ``particle_cloud``; compiled loops in
``particle_kernels``) and the reference-point Markov chain (``markov_chain``). The Kalman
state the PDR engines share is ``engines.shared.pdr_kalman``."""
