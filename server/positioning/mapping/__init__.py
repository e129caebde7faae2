"""Map building as pure steps: survey and crowdsourced points in, radio and magnetic maps out."""
