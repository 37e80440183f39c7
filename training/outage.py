"""OutageNet: a full DVL outage (the "ST-BeamsNet" case of the BeamsNet line of work).
An IMU window plus the last valid DVL velocity and the time since it -> the current
3-D body-frame velocity, used as a velocity pseudo-measurement at 1 Hz while the DVL
is out (up to 60 s).

Small on purpose (training shares 2 CPU cores):
- IMU: acc and gyro stacked (6 x 100), Conv1d(6 -> 8, kernel 10, stride 10) + Tanh,
  flatten (80), Linear 80 -> 32 + ReLU;
- concatenated with the last velocity (3) and the elapsed time (1, scaled by 1/60),
  Linear 36 -> 32 + ReLU, Linear 32 -> 3;
- output = last velocity + that correction (the velocity persists; the network predicts
  how it changed, from the current motion the IMU shows and the time elapsed).

Inputs are already normalised (see train_outage.py and models/outage.json).
"""

import torch
from torch import nn

WINDOW = 100


class OutageNet(nn.Module):
    """forward(acc [B,3,100], gyro [B,3,100], last_velocity [B,3], elapsed [B,1]) -> velocity [B,3]."""

    def __init__(self):
        super().__init__()
        self.conv = nn.Conv1d(6, 8, kernel_size=10, stride=10)
        self.imu = nn.Linear(8 * (WINDOW // 10), 32)
        self.mix = nn.Linear(32 + 4, 32)
        self.out = nn.Linear(32, 3)

    def forward(
        self, acc: torch.Tensor, gyro: torch.Tensor, last_velocity: torch.Tensor, elapsed: torch.Tensor
    ) -> torch.Tensor:
        x = torch.tanh(self.conv(torch.cat((acc, gyro), dim=1))).flatten(1)
        x = torch.relu(self.imu(x))
        x = torch.relu(self.mix(torch.cat((x, last_velocity, elapsed), dim=1)))
        return last_velocity + self.out(x)
