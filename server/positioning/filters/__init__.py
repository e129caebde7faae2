"""Estimators, independent of what they estimate from: Kalman steps (``kalman``) and the
state the Kalman filter engines share (``pdr_kalman``), the particle filter (``particle``,
``particle_cloud``, compiled loops in ``particle_kernels``), the reference-point Markov
chain (``markov_chain``) and the hidden Markov model of the floor (``floor_hmm``)."""
