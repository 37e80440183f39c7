"""BeamsNetV1 (Cohen & Klein, "BeamsNet: A data-driven approach enhancing Doppler
velocity log measurements for AUV navigation", Eng. Appl. of AI 114, 2022).

Architecture as described in ../shared/data/README.md:
- two IMU heads (accelerometer 3x100, gyroscope 3x100) through ONE shared
  Conv1d(3 -> 6, kernel 2) + Tanh,
- flatten both (2 x 6 x 99 = 1188), dropout 0.2,
- Linear 1188 -> 512 -> 256 -> 64 with ReLU, then Linear 64 -> 2,
- concatenate with the 4 beams (6 values), Linear 6 -> 3 (body-frame velocity).

Inputs are already normalised (see train_beamsnet.py and models/beamsnet.json);
the normalisation is NOT part of the exported graph.
"""

import torch
from torch import nn

WINDOW = 100
CONV_OUT = 6
KERNEL = 2
FLAT = 2 * CONV_OUT * (WINDOW - KERNEL + 1)  # 1188


class BeamsNetV1(nn.Module):
    """BeamsNetV1: forward(acc [B,3,100], gyro [B,3,100], beams [B,4]) -> velocity [B,3]."""

    def __init__(self, dropout: float = 0.2):
        super().__init__()
        self.conv = nn.Conv1d(3, CONV_OUT, kernel_size=KERNEL)  # shared by both heads
        self.dropout = nn.Dropout(dropout)
        self.fc1 = nn.Linear(FLAT, 512)
        self.fc2 = nn.Linear(512, 256)
        self.fc3 = nn.Linear(256, 64)
        self.fc4 = nn.Linear(64, 2)
        self.head = nn.Linear(2 + 4, 3)

    def forward(self, acc: torch.Tensor, gyro: torch.Tensor, beams: torch.Tensor) -> torch.Tensor:
        a = torch.tanh(self.conv(acc)).flatten(1)
        g = torch.tanh(self.conv(gyro)).flatten(1)
        x = self.dropout(torch.cat((a, g), dim=1))
        x = torch.relu(self.fc1(x))
        x = torch.relu(self.fc2(x))
        x = torch.relu(self.fc3(x))
        x = self.fc4(x)
        return self.head(torch.cat((x, beams), dim=1))
