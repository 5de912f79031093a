"""The learned motion prior: temporal-convolution autoencoder (Lohit et al.) run with onnxruntime.

Modules (run time needs numpy + onnxruntime only; torch is imported by training alone):

* ``runtime``   -- ``Prior.load(path=None)`` (default: the shipped Kinect v2 model in
  ``models/``), ``encode``/``decode``/``reconstruct`` (D(E(Y)) in metres, batched);
* ``latent``    -- ``fit_latent``: D(z*) of Eq. (1) by Levenberg-Marquardt, observed joints
  kept within ``fit_tol_m``;
* ``init``      -- ``prior_initial_guess`` (any length/rate, the solver's ``init=``),
  ``solver_params_for_prior_init``, ``fill_long_gaps`` (joints missing too long for the solver);
* ``normalize`` -- root-relative, scale- and facing-normalised windows (numpy);
* ``data``      -- takes, held-out split, window sampling and augmentation (numpy);
* ``model``/``train`` -- the torch autoencoder, ambient training, ONNX export (``streamfix train-prior``).
"""
