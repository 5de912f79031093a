"""The learned motion prior: temporal-convolution autoencoder (Lohit et al.) run with onnxruntime.

One model for every sensor: motions are mapped onto the canonical 20-joint body
(``streamfix.canonical``: Kinect v2, Azure Kinect, Kinect v1/UI-PRMD, COCO-17, BlazePose-33),
reconstructed there and mapped back; joints a layout lacks are simply unobserved.

Modules (run time needs numpy + onnxruntime only; torch is imported by training alone):

* ``runtime``   -- ``Prior.load(path=None)`` (default: the shipped model in ``models/``,
  card ``models/canonical.md``), ``set_default_prior`` (``serve/clean --prior``),
  ``encode``/``decode``/``reconstruct`` (D(E(Y)) in metres, batched);
* ``latent``    -- ``fit_latent``: D(z*) of Eq. (1) by Levenberg-Marquardt (or its chord
  variant), observed joints kept within ``fit_tol_m``;
* ``init``      -- ``prior_initial_guess`` (any layout/length/rate, the solver's ``init=``),
  ``solver_params_for_prior_init``, ``fill_long_gaps`` (joints missing too long for the solver);
* ``plausibility`` -- ``limb_residuals``: leave-one-limb-out residuals, for swapped/broken limbs;
* ``normalize`` -- root-relative, scale- and facing-normalised windows (numpy);
* ``data``      -- held-out split, window sampling and augmentation (numpy; takes from
  ``streamfix.io.prior_takes``);
* ``model``/``train`` -- the torch autoencoder, ambient training, ONNX export (``streamfix train-prior``).
"""
