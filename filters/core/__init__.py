"""Generic estimation cores (state-size agnostic): EKF, UKF, federated fusion."""
