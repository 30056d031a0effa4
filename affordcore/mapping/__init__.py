"""Fields to maps: every pose scored, the places and their probabilities, the outputs people and robots
read."""
