"""coopsim: cooperative-manipulator closed-chain dynamics, validated against MuJoCo."""
