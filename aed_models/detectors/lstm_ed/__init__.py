"""LSTMED: rollout-only LSTM baseline."""

from aed_models.detectors.lstm_ed.configuration_lstm_ed import LSTMEDConfig

__all__ = ["LSTMEDConfig"]
